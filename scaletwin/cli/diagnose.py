"""``scaletwin diagnose REAL``: locate where a real recording and its twin differ, name the missing physics, fit
it, and show the residual before and after (held-out cycles with ``--held-out``).

REAL is a recording (our Parquet, or a CSV/Parquet log with ``name [unit]`` headers) holding the commands. The
twin is rebuilt from its provenance unless ``--twin`` names one (a JSON file or ``SCALE[:SOIL]``).
"""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("diagnose", help="locate, name and model sim-vs-real discrepancies of a recording")
    p.add_argument("real", metavar="REAL", help="recording with commands (.parquet or .csv)")
    p.add_argument("--twin", metavar="SPEC", help="twin: JSON file {scale, soil, env_kwargs, seed} or SCALE[:SOIL] "
                   "(default: the recording's provenance)")
    p.add_argument("--held-out", nargs="*", default=[], metavar="REC", help="further cycles for the before/after")
    p.add_argument("--json", metavar="OUT", help="write the JSON report")
    p.add_argument("--rrd", metavar="OUT", help="write a rerun recording (real, twin, corrected overlaid)")
    p.add_argument("--report", metavar="OUT.md", help="write a Markdown report with plots")
    p.add_argument("--workers", type=int, default=1, help="processes replaying the twin (default 1)")
    p.add_argument("--seed", type=int, default=0, help="seed of the null runs and the bootstrap (default 0)")
    p.add_argument("--budget", type=int, default=None, metavar="REPLAYS",
                   help="twin replays after which the search stops (deterministic; "
                        "default: discrepancy.search.budget.REPLAYS)")
    p.add_argument("--time-budget", type=float, default=None, metavar="SECONDS",
                   help="wall-clock seconds after which the search stops, a safety net reported in the output "
                        "(default: discrepancy.search.budget.SECONDS)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from discrepancy import DiagnoseOptions, NullSpec, diagnose
    from discrepancy.report.document import to_json, write_json, write_markdown

    limits = {k: v for k, v in (("budget", args.budget), ("time_budget", args.time_budget)) if v is not None}
    options = DiagnoseOptions(workers=args.workers, null=NullSpec(seed=args.seed), seed=args.seed, **limits)
    d = diagnose(args.real, args.twin, held_out=args.held_out, options=options)
    to_json(d)  # validates
    console = Console()
    cut = f", search cut short by its {d.budget.cut} budget" if d.budget and d.budget.cut else ""
    table = Table(title=f"{d.train.name}: {len(d.located)} located windows, {d.simulations} twin replays, "
                        f"{d.timings['total']:.1f} s{cut}")
    for col in ("effect", "target", "parameters (SI)", "confidence", "confounded with"):
        table.add_column(col)
    for e in d.effects:
        params = ", ".join(f"{k}={v:.4g}" for k, v in e.parameters.items())
        table.add_row(e.effect, e.target or "-", params or "-", f"{e.confidence:.2f}", ", ".join(e.confounded_with))
    if not d.effects:
        table.add_row("(none)", "-", "-", "-", "nothing differs beyond noise" if not d.located else "")
    console.print(table)
    for flag, path, writer in (("json", args.json, write_json), ("report", args.report, write_markdown)):
        if path:
            writer(d, path)
            console.print(f"{flag}: {path}")
    if args.rrd:
        from discrepancy.report.rerun_out import write_rrd

        write_rrd(d, args.rrd)
        console.print(f"rrd: {args.rrd}")
    return 0
