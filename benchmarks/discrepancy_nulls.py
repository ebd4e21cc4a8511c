"""The benchmark's null cases alone (nothing planted), every noise family and input condition as dealt, full
``diagnose``: the false-alarm side of issue 14 measured on more nulls than a 20-case run holds (6 per seed).

One JSON line per null (seed, case, noise, input, machine, what was located and named, time), appended as each ends
(nothing is lost on interruption; a rerun skips the nulls already in OUT). ``--conditions`` keeps the nulls dealt
one of those input conditions (e.g. the resampled logs: ``50hz,200hz,500hz``). Usage::

    python benchmarks/discrepancy_nulls.py OUT.jsonl 24,25,26 [--workers 2] [--conditions 200hz,500hz]
    python benchmarks/discrepancy_nulls.py OUT.jsonl --render > OUT.md   # the Markdown of what OUT holds
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from discrepancy.bench.cases import KIND_PATTERN, make_case
from discrepancy.bench.logs import CONDITIONS
from discrepancy.bench.run import run_case
from discrepancy.pipeline import DiagnoseOptions

#: Search clock of each diagnosis, s (a safety net: a clean null ends long before).
TIME_BUDGET = 150.0


def one(key: tuple[int, int]) -> dict[str, Any]:
    """Diagnose null case ``key`` = (seed, index) of the benchmark; the row written for it."""
    seed, index = key
    case = make_case(index, seed)
    t = time.time()
    r = run_case(case, DiagnoseOptions(workers=1, time_budget=TIME_BUDGET))
    return {"seed": seed, "index": index, "family": case.noise.family, "noise": case.noise.describe(),
            "input": case.condition.describe(), "scale": case.meta.get("scale"), "soil": case.meta.get("soil"),
            "located": r.get("located_pairs"), "named": r.get("named"), "error": r.get("error"),
            "start_check": r.get("start_check"), "s": round(time.time() - t, 1), "replays": r.get("simulations"),
            "clean": (not r.get("error")) and not r.get("named")}


def render(rows: list[dict[str, Any]]) -> str:
    """Markdown of null rows: clean per noise family and per input condition, then every null."""
    def table(label: str, key: str) -> list[str]:
        groups: dict[str, list[dict[str, Any]]] = {}
        for r in rows:
            groups.setdefault(r[key].split()[0] if key == "input" else r[key], []).append(r)
        lines = [f"| {label} | nulls | clean |", "|---|---|---|"]
        lines += [f"| {g} | {len(rs)} | {sum(r['clean'] for r in rs)} |" for g, rs in sorted(groups.items())]
        return [*lines, f"| all | {len(rows)} | {sum(r['clean'] for r in rows)} |", ""]

    def named(r: dict[str, Any]) -> str:
        if r.get("error"):
            return "error: " + str(r["error"])
        return ", ".join(f"{n}[{t}]" if t else str(n) for n, t in r["named"]) or "clean"

    times = sorted(r["s"] for r in rows)
    lines = [f"{len(rows)} nulls, {sum(r['clean'] for r in rows)} clean (nothing named, nothing `unexplained`); "
             f"diagnosis time median {times[len(times) // 2]:.1f} s, max {times[-1]:.1f} s.", "",
             *table("noise family", "family"), *table("input condition", "input"),
             "| seed:case | noise | input | machine | named |", "|---|---|---|---|---|"]
    lines += [f"| {r['seed']}:{r['index']} | {r['noise']} | {r['input']} | {r['scale']} {r['soil']} | {named(r)} |"
              for r in sorted(rows, key=lambda r: (r["seed"], r["index"]))]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="JSON lines, appended")
    ap.add_argument("seeds", nargs="?", help="comma-separated master seeds")
    ap.add_argument("--render", action="store_true", help="print the Markdown of OUT and stop")
    ap.add_argument("--workers", type=int, default=2, help="nulls diagnosed at once (default 2)")
    ap.add_argument("--conditions", default=None, help=f"comma-separated input conditions to keep ({CONDITIONS})")
    args = ap.parse_args()
    if args.render:
        print(render([json.loads(line) for line in Path(args.out).read_text().splitlines()]), end="")
        return
    if not args.seeds:
        ap.error("give the seeds (or --render)")
    keep = set(args.conditions.split(",")) if args.conditions else set(CONDITIONS)
    if unknown := sorted(keep - set(CONDITIONS)):
        ap.error(f"unknown conditions {unknown}; choose from {list(CONDITIONS)}")
    done = set()
    if Path(args.out).exists():
        done = {(r["seed"], r["index"]) for r in map(json.loads, Path(args.out).read_text().splitlines())}
    nulls = [i for i, k in enumerate(KIND_PATTERN) if k == "null"]
    todo = [(int(s), i) for s in args.seeds.split(",") for i in nulls
            if (int(s), i) not in done and make_case(i, int(s)).condition.name in keep]
    with ProcessPoolExecutor(args.workers) as ex, open(args.out, "a") as f:
        for row in ex.map(one, todo):
            f.write(json.dumps(row) + "\n")
            f.flush()
            verdict = "clean" if row["clean"] else f"named {row['named']} error {row['error']}"
            print(row["seed"], row["index"], row["family"], row["input"], verdict, row["s"], flush=True)


if __name__ == "__main__":
    main()
