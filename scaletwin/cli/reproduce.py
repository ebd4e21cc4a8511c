"""``scaletwin reproduce``: the paper's results in one command, with a report beside the paper's figures.

Simulates the standard data set (ER12 + WA475 dig cycles and static holds) and the held-out machines, runs the FFNN
grid search (48 configurations), fits every model with the best FFNN, draws the paper's figures, validates on the
miniature and writes ``report.md`` into ``--out``. About 20 minutes on two cores; ``--quick`` is a minute-long
smoke run on tiny data (its numbers mean nothing). Reruns reuse finished episodes and grid rows.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from scaletwin.cli.common import add_executor_args, executor_from_args

DEFAULT_OUT = Path("scaletwin-reproduce")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("reproduce", help="reproduce the paper end to end and write a side-by-side report")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output directory (default ./{DEFAULT_OUT})")
    p.add_argument("--quick", action="store_true", help="tiny data, tiny grid, few epochs: a smoke run")
    p.add_argument("--workers", default=None,
                   help="processes for simulations and the grid (integer or 'serial'; default all cores)")
    p.add_argument("--no-rerun", action="store_true", help="do not write rerun logs of the fits")
    add_executor_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    executor = executor_from_args(args, args.workers)  # before the heavy imports: bad options fail at once
    from rich.console import Console

    from scaling.runs.report import headline_rows, write_report
    from scaling.runs.reproduce import QUICK, ReproduceConfig, reproduce

    console = Console()
    config = QUICK if args.quick else ReproduceConfig()
    console.print(f"[bold]Reproducing[/bold] into {args.out}/ ({'quick smoke run' if args.quick else 'full'}): "
                  "data -> grid search -> fits -> figures -> miniature -> report")
    result = reproduce(args.out, config, executor, progress=True, rerun=not args.no_rerun)
    write_report(result, args.out / "report.md")
    for quantity, paper, ours, target, met in headline_rows(result):
        console.print(f"  {quantity}: ours {ours} (paper {paper}; target {target}: {met})")
    console.print(f"report: {args.out / 'report.md'}; timings (s): "
                  + ", ".join(f"{k} {v:.0f}" for k, v in result.seconds.items()))
    return 0
