"""``scaletwin validate-mini``: the paper's section 4 — fitted δ1 models predict F21 on the 11 kg miniature.

The miniature is solved analytically at static equilibrium under loads of 0.5–4 kg
(:mod:`scaling.evaluation.miniature`); every model of a ``scaletwin fit`` directory predicts F21 there from the ER12
reference row, ``direct-pi`` (δ1 ≡ 1) included. Prints the table, saves the figure (error against load) and, with
``--json FILE``, writes ``{"loads_kg": [...], "models": {NAME: {"mean_abs_pct_error": x, "pct_error": [...]}}}`` (signed
% errors). Without a run directory (and no ``./scaletwin-fit``), the demo models are fitted first into
``./scaletwin-fit``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from scaletwin.cli import CommandError
from scaletwin.cli.common import mini_table
from scaletwin.cli.demo import fit_demo

DEFAULT_RUN = Path("scaletwin-fit")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("validate-mini", help="scale F21 to the 11 kg miniature at rest and report the errors")
    p.add_argument("run_dir", nargs="?", type=Path, default=None,
                   help=f"a `scaletwin fit` output directory (default ./{DEFAULT_RUN}; fitted with the demo "
                        "settings if absent)")
    p.add_argument("--json", metavar="FILE", type=Path, help="write the loads and per-model errors as JSON")
    p.add_argument("--figure", metavar="PNG", type=Path, help="error-against-load figure (default RUN/mini.png)")
    p.add_argument("--loads", help="comma list of loads in kg (default 0.5 to 4 in 8 steps: "
                                    "scaling.evaluation.miniature.LOADS)")
    p.add_argument("--check-env", action="store_true",
                   help="also settle the simulator's MuJoCo model at each load and show its F21 (cross-check)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np
    from rich.console import Console

    from scaling.evaluation.miniature import DIRECT_PI, LOADS, env_at_rest, static_rows, validate_mini
    from scaling.runs.plots import plot_mini_validation
    from scaling.runs.provenance import provenance, write_json

    console = Console()
    run_dir = args.run_dir or DEFAULT_RUN
    if args.run_dir is not None and not Path(args.run_dir).exists():
        raise CommandError(f"no run directory {args.run_dir}; create one with `scaletwin fit --out {args.run_dir}`")
    if args.run_dir is None and not (run_dir / "reference.json").exists():
        console.print(f"[bold]No fitted models given: fitting the demo models into ./{run_dir} first[/bold]")
        fit_demo(run_dir, console)
    from scaling.runs.run_io import load_run

    try:
        loads = LOADS if args.loads is None else tuple(float(x) for x in args.loads.split(",") if x.strip())
    except ValueError as exc:
        raise CommandError(f"--loads must be a comma list of numbers, got {args.loads!r}") from exc
    if not loads or min(loads) <= 0:
        raise CommandError("--loads needs positive loads in kg")
    models, reference = load_run(run_dir)
    mini = validate_mini(models, reference, static_rows("mini", loads))
    env_f21 = np.array([env_at_rest("mini", x)["F21"] for x in loads]) if args.check_env else None
    console.print(mini_table(mini, f"Miniature (11 kg) at rest: F21 scaled from ER12 row {reference.name}", env_f21))
    if "ffnn" in mini.predicted and DIRECT_PI in mini.predicted:
        reduction = 100 * mini.reduction("ffnn")
        console.print(f"FFNN error reduction against direct Buckingham-Pi scaling: {reduction:.1f} %")
    figure = args.figure or run_dir / "mini.png"
    plot_mini_validation(mini, figure)
    console.print(f"figure: {figure}")
    if args.json:
        write_json(args.json, mini.to_json())
        write_json(Path(str(args.json) + ".provenance.json"),
                   provenance("validation", {"run_dir": str(run_dir), "loads_kg": list(loads)}))
        console.print(f"json: {args.json}")
    return 0
