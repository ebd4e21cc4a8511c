"""``scaletwin fit``: recordings → group sets → δ1 models → a model directory with metrics and provenance.

``--data DIR`` is a folder of Parquet recordings (``scaletwin_envs.recording`` sweeps, or ``scaling.data.recordings``
folders), used as it is. Without it, the ``--dataset`` preset is simulated into ``OUT/data/train`` (resumable).
``--held-out DIR`` holds machines never trained on (default: the held-out preset, λ = 0.5 and 2.5, simulated into
``OUT/data/held_out``). The output directory layout is
described in :mod:`scaling.runs.run_io`; every fit is logged to ``models/<name>/fit.rrd`` (rerun).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from scaletwin.cli import CommandError
from scaletwin.cli.common import add_executor_args, executor_from_args

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["register", "run"]

DEFAULT_OUT = Path("scaletwin-fit")
#: ``scaling.data.recordings.PRESETS`` and ``scaling.runs.pipeline.DEFAULT_MODELS`` by name, spelt out so that
#: registering the
#: command (``scaletwin --help``) imports neither (torch, MuJoCo); tests/test_cli_behaviour.py checks they agree.
DATASET_PRESETS = ("demo", "held_out", "small", "standard", "tiny")
MODEL_NAMES = ("ffnn", "ffnn-pose", "gru-eq10", "gru-eq23", "power-law", "direct-pi", "deep-ensemble")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fit", help="fit δ1 scaling models on recordings; write models, metrics and provenance")
    p.add_argument("--data", help="recordings folder or filesystem URI (s3://...), used as it is (default: simulate "
                                  "--dataset into OUT/data/train)")
    p.add_argument("--dataset", default="standard", choices=DATASET_PRESETS,
                   help="preset simulated when no --data is given (default standard: ER12 + WA475)")
    p.add_argument("--held-out", help="recordings (folder or URI) of machines never trained on "
                                      "(default OUT/data/held_out, simulated: λ = 0.5 and 2.5)")
    p.add_argument("--no-held-out", action="store_true", help="skip the machines never trained on")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"model directory (default ./{DEFAULT_OUT})")
    p.add_argument("--models", default=",".join(MODEL_NAMES),
                   help="comma list (default: all): " + ", ".join(MODEL_NAMES))
    p.add_argument("--reference", default="static", choices=("static", "random"),
                   help="ER12 reference row: drawn among rows at rest (default) or among all rows")
    p.add_argument("--seed", type=int, default=0, help="seed of split, reference draw and fits (default 0)")
    p.add_argument("--epochs", type=int, help="cap the training epochs of the neural models (quick runs)")
    p.add_argument("--workers", default=None, help="processes for simulations (integer or 'serial'; default all)")
    add_executor_args(p)
    p.add_argument("--no-rerun", action="store_true", help="do not write rerun logs of the fits")
    p.set_defaults(func=run)


def _data(given: str | None, default: Path, preset: str, executor: Any) -> pd.DataFrame:
    """Recordings of ``given`` (a folder or filesystem URI) as they are, or of ``preset`` simulated into ``default``
    (resumable) through ``executor`` (see :func:`scaletwin.cli.common.executor_from_args`)."""
    from scaletwin_envs.recording.atomic import exists
    from scaling.data.recordings import PRESETS, load_or_generate, load_recordings

    if given is None:
        return load_or_generate(default, PRESETS[preset], executor)
    if not exists(given):
        raise CommandError(f"no recordings folder {given}")
    return load_recordings(given)


def run(args: argparse.Namespace) -> int:
    executor = executor_from_args(args, args.workers)  # before the heavy imports: bad options fail at once
    from rich.console import Console
    from rich.table import Table

    from scaling.data.recordings import DataBundle
    from scaling.runs.pipeline import PipelineConfig, ScalingPipeline, model_specs
    from scaling.runs.run_io import save_run

    console = Console()
    out: Path = args.out
    names = [n.strip() for n in args.models.split(",") if n.strip()]
    try:
        specs = model_specs(names)
    except ValueError as exc:
        raise CommandError(str(exc)) from exc
    if args.epochs is not None:
        if args.epochs < 1:
            raise CommandError("--epochs must be >= 1")
        specs = tuple(replace(s, config={**s.config, "epochs": args.epochs}) if "epochs" in s.config else s
                      for s in specs)
    train = _data(args.data, out / "data" / "train", args.dataset, executor)
    held = None if args.no_held_out else _data(args.held_out, out / "data" / "held_out", "held_out", executor)
    machines = ", ".join(sorted(train["machine"].astype(str).unique()))
    console.print(f"training: {len(train)} rows of {machines}" + ("" if held is None else
                  f"; never trained on: {len(held)} rows of " + ", ".join(sorted(held["machine"].unique()))))
    config = PipelineConfig(models=specs, reference=args.reference, seed=args.seed)
    result = ScalingPipeline(config).run(DataBundle(train, held), progress=True)
    save_run(result, out, rerun=not args.no_rerun)
    table = Table(title=f"held-out episodes (reference ER12 row {result.reference.name})")
    for col in ("model", "R² δ1 dig", "R² δ1 all", "R² ln δ1", "F21 MAPE %", "mini |err| %", "fit s"):
        table.add_column(col, justify="right")
    for name, m in result.metrics.items():
        table.add_row(name, f"{m.get('r2_dig', float('nan')):.4f}", f"{m['r2']:.4f}", f"{m['r2_log']:.4f}",
                      f"{m['f21_mape_pct']:.2f}", f"{result.mini.mean_abs(name):.2f}", f"{m['fit_s']:.1f}")
    console.print(table)
    for name, per in result.held_out.items():
        cells = "; ".join(f"{mach}: F21 MAPE {v['f21_mape_pct']:.2f} %"
                          + (f", 90 % coverage {100 * v['coverage_90']:.1f} %" if "coverage_90" in v else "")
                          for mach, v in per.items())
        console.print(f"never trained on, {name}: {cells}")
    console.print(f"models, metrics.json and provenance.json in {out}/")
    return 0
