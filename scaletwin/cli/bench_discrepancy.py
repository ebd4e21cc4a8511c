"""``scaletwin bench-discrepancy --cases N --seed S``: plant hidden physics in the twin, read it through drawn sensor
noise (white, AR(1), drift, quantised, low-pass), deliver it under a drawn input condition (in memory, or CSV field
logs at the control step, 50/200/500 Hz, with a time offset or a missing channel), diagnose it blind, score it
(overall, per noise family and per input condition) and write the results: Markdown (default
``benchmarks/results/discrepancy.md``), one JSON line per case and a CSV per case beside it.

Resumable: every case is appended to the JSONL as it finishes (with the header of the run that made it: host,
cores, date, load average, git revision, seeds, case count); a rerun with the same seeds reads it back and skips
the cases already there (the same case: same seed, index and draw), so Ctrl-C loses at most the running cases.
``--fresh`` starts over. Cases that raised are recorded as errors and counted as finished unless ``--retry-errors``.
"""

from __future__ import annotations

import argparse
import csv
import datetime as dt
import json
import os
import platform
from pathlib import Path
from typing import Any

DEFAULT_OUT = "benchmarks/results/discrepancy.md"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench-discrepancy", help="benchmark the discrepancy tool on planted, hidden physics")
    p.add_argument("--cases", type=int, default=20, help="number of cases per seed (default 20)")
    p.add_argument("--seed", type=int, nargs="+", default=[0], help="master seed(s) (default 0)")
    p.add_argument("--families", default=None,
                   help="comma-separated noise families to deal (default all: white,ar1,drift,quantised,lowpass)")
    p.add_argument("--conditions", default=None,
                   help="comma-separated input conditions to deal (default all: native,csv,50hz,200hz,500hz,offset,"
                        "missing)")
    p.add_argument("--workers", type=int, default=1, help="cases diagnosed in parallel (default 1)")
    p.add_argument("--diagnosis-workers", type=int, default=1,
                   help="replay processes of each diagnosis (default 1; with --workers 1 and 2 here, every case is "
                        "timed as one diagnosis on 2 cores)")
    p.add_argument("--budget", type=int, default=None, metavar="REPLAYS", help="replay budget of each diagnosis")
    p.add_argument("--time-budget", type=float, default=None, metavar="SECONDS",
                   help="wall-clock budget of each diagnosis's search (a safety net; default as `diagnose`)")
    p.add_argument("--out", default=DEFAULT_OUT, help=f"Markdown results (default {DEFAULT_OUT})")
    p.add_argument("--jsonl", metavar="FILE", help="one JSON line per case, the resume log (default: --out with "
                                                   "suffix _cases.jsonl)")
    p.add_argument("--csv", metavar="FILE", help="one CSV row per case (default: --out with suffix _cases.csv)")
    p.add_argument("--fresh", action="store_true", help="ignore (and overwrite) the results of an earlier run")
    p.add_argument("--retry-errors", action="store_true", help="rerun cases that raised in an earlier run")
    p.add_argument("--keep-logs", metavar="DIR", help="keep each case's field logs (CSV, twin JSON) under DIR")
    p.set_defaults(func=run)


def _names(text: str | None, known: tuple[str, ...], what: str) -> tuple[str, ...] | None:
    if not text:
        return None
    names = tuple(dict.fromkeys(n.strip() for n in text.split(",") if n.strip()))
    bad = [n for n in names if n not in known]
    if bad or not names:
        raise ValueError(f"--{what}: unknown {bad or text!r}; choose from {','.join(known)}")
    return names




def _git_revision() -> str:
    from scaletwin_envs.host import git_revision  # here: importing scaletwin_envs registers the envs (slow --help)

    return git_revision()


def run_header(args: argparse.Namespace, n_cases: int, options: Any) -> dict[str, Any]:
    """Where and how this run ran: host, cores, date, load average, git revision, seeds, case count, settings."""
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    return {"host": platform.node(), "machine": platform.machine(), "cores": os.cpu_count(),
            "date": dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
            "load_average": [round(x, 2) for x in load] if load else None, "git_rev": _git_revision(),
            "seeds": list(args.seed), "cases_per_seed": args.cases, "case_count": n_cases,
            "families": args.families or "all", "conditions": args.conditions or "all", "workers": args.workers,
            "diagnosis_workers": args.diagnosis_workers, "budget": options.budget, "time_budget": options.time_budget}


def _header_text(h: dict[str, Any]) -> str:
    load = "/".join(f"{x:.1f}" for x in h["load_average"]) if h["load_average"] else "n/a"
    return (f"# Discrepancy benchmark\n\nhost {h['host']} ({h['machine']}, {h['cores']} cores), {h['date']}, "
            f"load average {load} (1/5/15 min, at the start), git {h['git_rev']}, seeds "
            f"{', '.join(map(str, h['seeds']))}, {h['case_count']} cases ({h['cases_per_seed']} per seed; families "
            f"{h['families']}, conditions {h['conditions']}), {h['workers']} case(s) at once, "
            f"{h['diagnosis_workers']} replay worker(s) per diagnosis, budget {h['budget']} replays / "
            f"{h['time_budget']:g} s.")


def read_results(path: Path) -> list[dict[str, Any]]:
    """Case results of a JSONL resume log (unreadable lines, e.g. one cut short by a crash, skipped)."""
    out = []
    if not path.is_file():
        return out
    for line in path.read_text().splitlines():
        try:
            doc = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(doc, dict) and "key" in doc:
            out.append(doc)
    return out


def write_csv(path: Path, results: list[dict[str, Any]], header: dict[str, Any]) -> None:
    """The per-case CSV: ``# key: value`` header lines, then one row per case."""
    from discrepancy.bench.scoring import CSV_COLUMNS, csv_row
    from scaletwin_envs.recording.atomic import atomic_path

    with atomic_path(path) as tmp, tmp.open("w", newline="") as f:
        for k, v in header.items():
            f.write(f"# {k}: {v}\n")
        w = csv.DictWriter(f, fieldnames=list(CSV_COLUMNS))
        w.writeheader()
        for r in results:
            w.writerow(csv_row(r))


def run(args: argparse.Namespace) -> int:
    from discrepancy.bench.cases import FAMILIES
    from discrepancy.bench.logs import CONDITIONS
    from discrepancy.bench.run import planned_cases, run_bench
    from discrepancy.bench.scoring import table
    from discrepancy.pipeline import DiagnoseOptions

    if args.cases < 1:
        raise ValueError(f"--cases must be >= 1, got {args.cases}")
    families = _names(args.families, FAMILIES, "families")
    conditions = _names(args.conditions, CONDITIONS, "conditions")
    out = Path(args.out)
    jsonl = Path(args.jsonl) if args.jsonl else out.with_name(out.stem + "_cases.jsonl")
    csv_path = Path(args.csv) if args.csv else out.with_name(out.stem + "_cases.csv")
    for p in (out, jsonl, csv_path):
        p.parent.mkdir(parents=True, exist_ok=True)
    limits = {k: v for k, v in (("budget", args.budget), ("time_budget", args.time_budget)) if v is not None}
    options = DiagnoseOptions(workers=args.diagnosis_workers, **limits)
    plan = planned_cases(args.cases, args.seed, families, conditions)
    order = {c.key(): i for i, c in enumerate(plan)}
    if args.fresh:
        jsonl.write_text("")
    earlier = {r["key"]: r for r in read_results(jsonl) if r["key"] in order}
    if args.retry_errors:
        earlier = {k: r for k, r in earlier.items() if not r.get("error")}
    header = run_header(args, len(plan), options)
    head = _header_text(header)
    done: dict[str, dict[str, Any]] = dict(earlier)
    if earlier:
        print(f"resuming: {len(earlier)} of {len(plan)} cases already in {jsonl}", flush=True)
    fam, cond = families or FAMILIES, conditions or CONDITIONS

    def write(note: str) -> None:
        results = sorted(done.values(), key=lambda r: order[r["key"]])
        out.write_text(table(results, f"{head}\n\n{note}" if note else head, fam, cond))
        write_csv(csv_path, results, header)

    def progress(result: dict[str, Any]) -> None:
        tag = (f"case {result['seed']}:{result['index']:3d} {result['kind']:6s} {result['noise']:28s} "
               f"{result['input']:16s}")
        if result.get("error"):
            print(f"{tag} ERROR {result['error'][:200]}", flush=True)
        else:
            named = ", ".join(n for n, _ in result["named"]) or "-"
            cut = (result.get("budget") or {}).get("cut")
            print(f"{tag} planted {result['planted'] or result['ooc'] or '-'} -> {named} "
                  f"({result['diagnosis_s']:.1f} s, {result['simulations']} replays{', cut: ' + cut if cut else ''})",
                  flush=True)
        result = {**result, "run": header}  # each line says where and when it ran (runs may be resumed elsewhere)
        with jsonl.open("a") as f:  # appended as each case finishes: an interrupted run keeps what it did
            f.write(json.dumps(result, default=str) + "\n")
        done[result["key"]] = result
        write(f"Partial: {len(done)} of {len(plan)} cases done.")

    try:
        run_bench(args.cases, args.seed, args.workers, progress, options, families, conditions, skip=set(earlier),
                  folder=args.keep_logs)
    except KeyboardInterrupt:
        write(f"Interrupted: {len(done)} of {len(plan)} cases done (rerun the same command to go on).")
        print(f"\ninterrupted: {len(done)} of {len(plan)} cases kept in {jsonl}; rerun to go on")
        return 130
    write("" if len(done) == len(plan) else f"{len(done)} of {len(plan)} cases.")
    print(out.read_text())
    print(f"per case: {jsonl}, {csv_path}")
    return 0
