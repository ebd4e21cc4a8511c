"""``scaletwin bench-discrepancy --cases N --seed S``: plant hidden physics in the twin, diagnose it blind, score
it (identification, localisation F1, parameter error and coverage, residual reduction, nulls, out-of-catalogue)
and write the results table (Markdown, default ``benchmarks/results/discrepancy.md``)."""

from __future__ import annotations

import argparse
import datetime as dt
import json
import platform
from pathlib import Path
from typing import Any

DEFAULT_OUT = "benchmarks/results/discrepancy.md"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench-discrepancy", help="benchmark the discrepancy tool on planted, hidden physics")
    p.add_argument("--cases", type=int, default=20, help="number of cases (default 20)")
    p.add_argument("--seed", type=int, default=0, help="master seed (default 0)")
    p.add_argument("--workers", type=int, default=1, help="cases diagnosed in parallel (default 1)")
    p.add_argument("--diagnosis-workers", type=int, default=1,
                   help="replay processes of each diagnosis (default 1; with --workers 1 and 2 here, every case is "
                        "timed as one diagnosis on 2 cores)")
    p.add_argument("--budget", type=int, default=None, metavar="REPLAYS", help="replay budget of each diagnosis")
    p.add_argument("--time-budget", type=float, default=None, metavar="SECONDS",
                   help="wall-clock budget of each diagnosis's search (a safety net; default as `diagnose`)")
    p.add_argument("--out", default=DEFAULT_OUT, help=f"Markdown results (default {DEFAULT_OUT})")
    p.add_argument("--jsonl", metavar="FILE", help="also write one JSON line per case")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from discrepancy.bench.run import run_bench
    from discrepancy.bench.scoring import table
    from discrepancy.pipeline import DiagnoseOptions

    if args.cases < 1:
        raise ValueError(f"--cases must be >= 1, got {args.cases}")
    jsonl = Path(args.jsonl) if args.jsonl else None
    if jsonl is not None:
        jsonl.parent.mkdir(parents=True, exist_ok=True)
        jsonl.write_text("")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    limits = {k: v for k, v in (("budget", args.budget), ("time_budget", args.time_budget)) if v is not None}
    options = DiagnoseOptions(workers=args.diagnosis_workers, **limits)
    header = (f"# Discrepancy benchmark ({dt.date.today()}, {args.cases} cases, seed {args.seed}, "
              f"{platform.machine()}, {args.workers} case(s) at once, {args.diagnosis_workers} replay worker(s) "
              f"per diagnosis, budget {options.budget} replays / {options.time_budget:g} s)")
    done: list[dict[str, Any]] = []

    def progress(result: dict[str, Any]) -> None:
        named = ", ".join(n for n, _ in result["named"]) or "-"
        print(f"case {result['index']:3d} {result['kind']:6s} planted {result['planted'] or result['ooc'] or '-'} "
              f"-> {named} ({result['diagnosis_s']:.1f} s, {result['simulations']} replays"
              f"{', cut: ' + result['budget']['cut'] if (result.get('budget') or {}).get('cut') else ''})", flush=True)
        if jsonl is not None:  # written as each case finishes, so an interrupted run keeps what it did
            with jsonl.open("a") as f:
                f.write(json.dumps(result) + "\n")
        done.append(result)  # the table so far, rewritten after every case
        partial = sorted(done, key=lambda r: r["index"])
        out.write_text(table(partial, f"{header}\n\nPartial: {len(done)} of {args.cases} cases done."))

    results = run_bench(args.cases, args.seed, args.workers, progress, options)
    text = table(results, header)
    print(text)
    out.write_text(text)
    return 0
