"""``scaletwin diagnose REAL``: locate where a real recording and its twin differ, name the missing physics, fit
it, and show the residual before and after (held-out cycles with ``--held-out``).

REAL is a recording (our Parquet, or a CSV/Parquet log with ``name [unit]`` headers) holding the commands. The
twin is rebuilt from its provenance unless ``--twin`` names one (a JSON file or ``SCALE[:SOIL]``).

Progress goes to stderr, one line per pipeline step with the seconds elapsed (``--quiet`` silences it); the result
goes to stdout, one block per effect with full targets, intervals and units, wrapped at the terminal's width
without cutting a name (:func:`discrepancy.report.document.text_report`).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable

from scaletwin.cli.common import add_executor_args, executor_from_args

#: Replay processes by default: one per core, at most this many. The diagnosis sends its replays in batches of 3–10
#: (the start fit's trial steps and Jacobians) up to a few tens (a screen of candidates); beyond 8 processes most
#: wait. On 2 cores, 2 processes against 1 took a single-effect diagnosis from 31 to 21 s (benchmark seed 92 case 3)
#: and a field-log one from 43 to 32 s (case 1), the same answers.
MAX_DEFAULT_WORKERS = 8


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("diagnose", help="locate, name and model sim-vs-real discrepancies of a recording")
    p.add_argument("real", metavar="REAL", help="recording with commands (.parquet or .csv)")
    p.add_argument("--twin", metavar="SPEC", help="twin: JSON file {scale, soil, env_kwargs, seed} or SCALE[:SOIL] "
                   "(default: the recording's provenance)")
    p.add_argument("--held-out", nargs="*", default=[], metavar="REC", help="further cycles for the before/after")
    p.add_argument("--json", metavar="OUT", help="write the JSON report")
    p.add_argument("--rrd", metavar="OUT", help="write a rerun recording (real, twin, corrected overlaid)")
    p.add_argument("--report", metavar="OUT.md", help="write a Markdown report with plots")
    p.add_argument("--workers", type=int, default=None,
                   help=f"local processes replaying the twin (default: one per core, at most {MAX_DEFAULT_WORKERS}; "
                        "1: in this process); the answer does not depend on it")
    add_executor_args(p)
    p.add_argument("--seed", type=int, default=0, help="seed of the null runs and the bootstrap (default 0)")
    p.add_argument("--budget", type=int, default=None, metavar="REPLAYS",
                   help="twin replays after which the search stops (deterministic; "
                        "default: discrepancy.search.budget.REPLAYS)")
    p.add_argument("--time-budget", type=float, default=None, metavar="SECONDS",
                   help="wall-clock seconds after which the search stops, a safety net reported in the output "
                        "(default: discrepancy.search.budget.SECONDS)")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.set_defaults(func=run)


def _progress(start: float) -> Callable[[str], None]:
    """A callback printing each step as it starts, with the seconds since ``start``, to stderr."""

    def report(step: str) -> None:
        print(f"[{time.perf_counter() - start:6.1f} s] {step}", file=sys.stderr, flush=True)

    return report


def run(args: argparse.Namespace) -> int:
    from discrepancy import DiagnoseOptions, NullSpec, diagnose
    from discrepancy.report.document import text_report, to_json, write_json, write_markdown

    start = time.perf_counter()
    progress = None if args.quiet else _progress(start)
    limits = {k: v for k, v in (("budget", args.budget), ("time_budget", args.time_budget)) if v is not None}
    executor = executor_from_args(args, args.workers)  # checks the combination of options
    local = args.executor in (None, "local") and args.ray_address is None
    workers = args.workers if args.workers is not None else min(os.cpu_count() or 1, MAX_DEFAULT_WORKERS)
    options = DiagnoseOptions(workers=workers if local else 1,
                              executor=None if local or executor == "serial" else executor,
                              null=NullSpec(seed=args.seed), seed=args.seed, progress=progress, **limits)
    d = diagnose(args.real, args.twin, held_out=args.held_out, options=options)
    if progress is not None:
        progress("done")
    to_json(d)  # validates
    print(text_report(d), end="")
    for flag, path, writer in (("json", args.json, write_json), ("report", args.report, write_markdown)):
        if path:
            writer(d, path)
            print(f"{flag}: {path}")
    if args.rrd:
        from discrepancy.report.rerun_out import write_rrd

        write_rrd(d, args.rrd)
        print(f"rrd: {args.rrd}")
    return 0
