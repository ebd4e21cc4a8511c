"""``scaletwin demo``: the main job on embedded defaults, in about 1.5 min on two CPU cores.

1. simulate a few ER12 and WA475 dig cycles (and static holds) with the scripted dig policy;
2. choose the Eq. (10) groups (π1 = F21/F31) with the paper's correlation filter;
3. fit an FFNN δ1 model and the direct Buckingham-Pi baseline (δ1 ≡ 1), logging the fit to rerun;
4. scale F21 from the ER12 twin to the 11 kg miniature at rest (0.5–4 kg loads) and print the error table;
5. scale the same rows with the zoo's product-line model ``statics-pl`` (matched ER12 rows as its source).

Outputs go to ``--out`` (default ``./scaletwin-demo``): ``data/`` (Parquet recordings), ``run/`` (models,
metrics, provenance, ``fit.rrd``), ``mini.json``, ``product_line_mini.json``, ``mini.png`` and
``pred_vs_actual_ffnn.png``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from scaletwin.cli.common import add_executor_args, executor_from_args, mini_table

if TYPE_CHECKING:
    from rich.console import Console

    from scaling.runs.pipeline import PipelineResult

DEFAULT_OUT = Path("scaletwin-demo")
#: Names of the demo models: the FFNN of a full fit (3×64) and the baseline.
DEMO_MODEL_NAMES = ("ffnn", "direct-pi")


def __getattr__(name: str) -> Any:
    """``DEMO`` (the data set spec) and ``DEMO_MODELS`` (the model specs), imported on first use: ``scaletwin
    --help`` must not import :mod:`scaling` (torch, MuJoCo). Assigning either attribute (tests) overrides it."""
    if name == "DEMO":
        from scaling.data.recordings import DEMO

        return DEMO
    if name == "DEMO_MODELS":
        from scaling.runs.pipeline import model_specs

        return model_specs(list(DEMO_MODEL_NAMES))
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _setting(name: str) -> Any:
    """A module setting: the value assigned to the module, else its lazy default (:func:`__getattr__`)."""
    return globals()[name] if name in globals() else __getattr__(name)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="simulate, fit FFNN and direct-Pi, scale F21 to the miniature (about 1.5 min)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output directory (default ./{DEFAULT_OUT})")
    p.add_argument("--workers", default=None,
                   help="local processes for the simulations: an integer, or 'serial' (default; the demo is small)")
    add_executor_args(p)
    p.add_argument("--seed", type=int, default=0, help="seed of the split, the reference draw and the fit")
    p.add_argument("--no-rerun", action="store_true", help="do not write the rerun log of the fit")
    p.set_defaults(func=run)


def fit_demo(out: Path, console: Console, workers: Any = "serial", seed: int = 0,
             rerun: bool = True, data_dir: Path | None = None) -> PipelineResult:
    """Simulate the demo data into ``data_dir`` (default ``out/data``) and fit the demo models into ``out``.

    ``workers`` is where the simulations run: anything :func:`scaletwin_envs.parallel.make_executor` takes (an
    integer, ``"serial"``, ``None`` for every core, or an executor such as a ``RayExecutor``). The fit itself runs
    in this process.
    """
    from scaling.data.recordings import DataBundle, load_or_generate
    from scaling.runs.pipeline import PipelineConfig, ScalingPipeline
    from scaling.runs.run_io import save_run

    demo = _setting("DEMO")
    data_dir = data_dir or out / "data"
    n_eps = len(demo.tasks())
    console.print(f"[bold]1/4[/bold] Simulating {n_eps} episodes of the ER12 (3.3 t) and WA475 (26 t): "
                  f"dig cycles in {', '.join(demo.soils)} soil, and static holds -> {data_dir}")
    train = load_or_generate(data_dir, demo, executor=workers, progress=True)
    console.print(f"      {len(train)} rows of F21, F31, Pf_tilt, Pf_lift, x_b, y_b, m_b, a1, alpha1, V1, w1")
    console.print("[bold]2/4[/bold] Choosing the Eq. (10) groups (paper's RMS-Pearson filter) and fitting the FFNN δ1 "
                  "model and the direct-Pi baseline (δ1 ≡ 1)")
    config = PipelineConfig(models=_setting("DEMO_MODELS"), seed=seed)
    result = ScalingPipeline(config).run(DataBundle(train), progress=True)
    save_run(result, out, rerun=rerun)
    return result


def product_line_on_mini(data_dir: Path, rows: Any) -> dict[str, Any]:
    """The zoo's ``statics-pl`` on the miniature's static rows ``rows``, sourced from the ER12 recordings in
    ``data_dir`` (each row paired with its matched ER12 row, :func:`scaling.data.product_line.match_rows`):
    ``{"loads_kg", "mean_abs_pct_error", "pct_error", "source_rows"}`` (% of the analytical F21)."""
    import numpy as np

    import zoo
    from scaletwin_envs.specs import make_loader
    from scaling.data.product_line import add_design_signals, match_rows
    from scaling.data.recordings import load_recordings

    frame = load_recordings(data_dir)
    source = add_design_signals(frame[frame["machine"] == "er12"].reset_index(drop=True), {"er12": make_loader("er12")})
    target = add_design_signals(rows.assign(machine="mini"), {"mini": make_loader("mini")})
    matched = match_rows(source, target)
    out = zoo.load("statics-pl").scale_force(source.iloc[matched], target)
    pct = 100 * (out.force / target["F21"].to_numpy(float) - 1)
    return {"model": "statics-pl", "loads_kg": target["load_kg"].tolist(),
            "mean_abs_pct_error": float(np.mean(np.abs(pct))), "pct_error": pct.tolist(),
            "source_rows": [int(i) for i in matched]}


def run(args: argparse.Namespace) -> int:
    executor = executor_from_args(args, args.workers, default="serial")  # before the heavy imports: bad options
    import numpy as np  # fail at once
    from rich.console import Console

    from scaling.evaluation.miniature import static_rows
    from scaling.runs.plots import plot_mini_validation, plot_predicted_vs_actual
    from scaling.runs.provenance import write_json

    console = Console()
    start = time.perf_counter()
    out: Path = args.out
    result = fit_demo(out / "run", console, executor, args.seed, not args.no_rerun, data_dir=out / "data")
    choice = result.choices["eq10"]
    console.print(f"      groups: π1 = {choice.output.expression()}; "
                  + ", ".join(g.expression() for g in choice.inputs))
    m = result.metrics["ffnn"]
    console.print(f"      FFNN on held-out dig cycles: R² of δ1 = {m.get('r2_dig', m['r2']):.4f} "
                  f"(all held-out rows {m['r2']:.4f}), fitted in {m['fit_s']:.1f} s")
    console.print("      (the demo fits the default 3×64 FFNN on half the standard data set, 24 dig cycles per "
                  "machine; `scaletwin reproduce` fits the full set with the grid's pick)")
    console.print("[bold]3/4[/bold] Scaling F21 from the ER12 twin to the 11 kg miniature at rest")
    mini = result.mini
    console.print(mini_table(mini, f"Miniature: F21 scaled from ER12 row {result.reference.name} "
                                   f"(π1 = {result.reference['F21'] / result.reference['F31']:.3f})"))
    ffnn, direct = mini.mean_abs("ffnn"), mini.mean_abs("direct-pi")
    console.print(f"FFNN mean error {ffnn:.2f} % vs direct Buckingham-Pi {direct:.2f} % (paper: 4.29 % vs 42.04 %);"
                  " the direct-Pi error depends on how far the reference row is from the miniature's state, see "
                  "`scaletwin reproduce`")
    pl = product_line_on_mini(out / "data", static_rows("mini", tuple(float(x) for x in mini.loads_kg)))
    console.print(f"[bold]4/4[/bold] The product line's model (zoo `statics-pl`, trained on the ER12 and 24 drawn "
                  f"designs, never on the miniature), same ER12 recordings as its source, each miniature row paired "
                  f"with the ER12 hold nearest in pose and fill: mean error {pl['mean_abs_pct_error']:.2f} % "
                  "(the miniature is a design of its own: one pair of machines cannot teach the FFNN above that)")
    write_json(out / "product_line_mini.json", pl)
    write_json(out / "mini.json", mini.to_json())
    plot_mini_validation(mini, out / "mini.png")
    test, kinds = result.test_sets["eq10"], result.test_kinds["eq10"]
    dig = test.subset(np.flatnonzero(kinds == "dig")) if np.any(kinds == "dig") else test
    plot_predicted_vs_actual(dig.delta, result.models["ffnn"].predict(dig), out / "pred_vs_actual_ffnn.png",
                             title="FFNN δ1 (Fig. 6)\nheld-out dig cycles")
    console.print(f"outputs in {out}/ (run/ models + metrics + fit.rrd, mini.json, product_line_mini.json, mini.png, "
                  f"pred_vs_actual_ffnn.png); {time.perf_counter() - start:.0f} s")
    return 0
