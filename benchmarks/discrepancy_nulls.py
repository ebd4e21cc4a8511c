"""The benchmark's null cases alone (nothing planted), every noise family and input condition as dealt, full
``diagnose``: the false-alarm side of issue 14 measured on more nulls than a 20-case run holds (6 per seed).

One JSON line per null (seed, case, noise, input, machine, what was located and named, time), appended as each ends
(a rerun appends; nothing is lost on interruption). Usage::

    python benchmarks/discrepancy_nulls.py OUT.jsonl 24,25,26 [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from discrepancy.bench.cases import KIND_PATTERN, make_case
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="JSON lines, appended")
    ap.add_argument("seeds", help="comma-separated master seeds")
    ap.add_argument("--workers", type=int, default=2, help="nulls diagnosed at once (default 2)")
    args = ap.parse_args()
    nulls = [i for i, k in enumerate(KIND_PATTERN) if k == "null"]
    todo = [(int(s), i) for s in args.seeds.split(",") for i in nulls]
    with ProcessPoolExecutor(args.workers) as ex, open(args.out, "a") as f:
        for row in ex.map(one, todo):
            f.write(json.dumps(row) + "\n")
            f.flush()
            verdict = "clean" if row["clean"] else f"named {row['named']} error {row['error']}"
            print(row["seed"], row["index"], row["family"], row["input"], verdict, row["s"], flush=True)


if __name__ == "__main__":
    main()
