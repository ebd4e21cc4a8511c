"""One-call reproduction of the paper's results: data → grid search → fits → figures → validation → report.

:func:`reproduce` writes into ``out_dir``::

    data/train, data/held_out   Parquet recordings (resumable; reruns reuse them)
    grid/results.csv            the FFNN grid search (paper Figs. 8–10), resumable
    run/                        the run directory of :mod:`scaling.runs.run_io` (models, metrics, provenance,
                                rerun logs)
    figures/*.png               our versions of the paper's figures (also in figures/figures.rrd for rerun)
    reference_sensitivity.csv   miniature errors of FFNN and direct-Pi for several reference rows
    report.md                   our figures and numbers beside the paper's (written from the result by
                                :func:`scaling.runs.report.write_report`)
    provenance.json, timings.json

The grid search runs on the pipeline's FFNN δ1 training pairs only: it fits on part of the training episodes and
scores R² of δ1 on the others (``grid_validation`` of them, split by episode); the best configuration becomes the
FFNN of the run, which is then scored on the held-out test episodes that the search never saw.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from scaletwin_envs.parallel import Executor
from scaling.data.recordings import HELD_OUT, STANDARD, TINY, DataBundle, DatasetSpec, load_or_generate, summary
from scaling.models.grid import DEFAULT_GRID, GridSearch, best_config
from scaling.runs import plots
from scaling.runs.pipeline import FFNN_CONFIG, ModelSpec, PipelineConfig, PipelineResult, ScalingPipeline, model_specs
from scaling.runs.provenance import provenance, write_json
from scaling.runs.run_io import save_run


@dataclass(frozen=True)
class ReproduceConfig:
    """What :func:`reproduce` runs (defaults: the full reproduction; :data:`QUICK` for tests)."""

    train: DatasetSpec = STANDARD
    held_out: DatasetSpec = HELD_OUT
    grid: Mapping[str, Sequence[Any]] = field(default_factory=lambda: dict(DEFAULT_GRID))
    grid_base: Mapping[str, Any] = field(default_factory=lambda: {k: v for k, v in FFNN_CONFIG.items()
                                                                  if k not in DEFAULT_GRID})
    pipeline: PipelineConfig = field(default_factory=PipelineConfig)
    reference_draws: int = 8
    grid_validation: float = 0.2


def _quick(spec: ModelSpec) -> ModelSpec:
    """``spec`` with few epochs (and two ensemble members): for smoke tests, not for numbers."""
    if spec.cls in ("FFNN", "GRUModel"):
        return replace(spec, config={**spec.config, "epochs": 30})
    if spec.cls == "DeepEnsemble":
        return replace(spec, config={**spec.config, "epochs": 30, "k": 2})
    return spec


QUICK = ReproduceConfig(
    train=TINY, held_out=replace(TINY, machines=(("lambda0.5", 0.5),), dig_seeds=2, hold_episodes=1, seed=100_000),
    grid={"hidden_layers": (1, 2), "units": (8, 32), "dropout": (0.0,), "lr": (3e-3,)},
    grid_base={"epochs": 60, "batch_size": 256, "patience": 20},
    pipeline=PipelineConfig(models=tuple(_quick(s) for s in model_specs())),
    reference_draws=2)


@dataclass
class ReproduceResult:
    out_dir: Path
    run: PipelineResult
    grid: pd.DataFrame
    sensitivity: pd.DataFrame
    figures: dict[str, Path]
    seconds: dict[str, float]
    data_summary: pd.DataFrame


def reproduce(out_dir: str | Path, config: ReproduceConfig | None = None,
              executor: str | int | Executor | None = None, progress: bool = True,
              rerun: bool = True) -> ReproduceResult:
    """Run the whole reproduction into ``out_dir`` (see module docstring; ``report.md`` is the next stage's:
    :func:`scaling.runs.report.write_report` of the result)."""
    cfg = config or ReproduceConfig()
    out = Path(out_dir)
    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    train = load_or_generate(out / "data" / "train", cfg.train, executor, progress)
    held = load_or_generate(out / "data" / "held_out", cfg.held_out, executor, progress)
    bundle = DataBundle(train, held)
    seconds["data"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    pipeline = ScalingPipeline(cfg.pipeline)
    prepared = pipeline.prepare(bundle.train)
    ffnn_groups = next(s.groups for s in cfg.pipeline.models if s.name == "ffnn")
    base = {**dict(cfg.grid_base), "rel_eps": cfg.pipeline.rel_eps, "seed": cfg.pipeline.seed, "threads": 1}
    search = GridSearch(cfg.grid, base, "FFNN", executor, out / "grid" / "results.csv", progress)
    grid_train, grid_val = prepared.sets[ffnn_groups][0].split_by_episode(cfg.grid_validation, cfg.pipeline.seed)
    grid = search.run(grid_train, grid_val)
    seconds["grid"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    best = best_config(grid)
    models = tuple(replace(s, config={**s.config, **{k: best[k] for k in cfg.grid}}) if s.name == "ffnn" else s
                   for s in cfg.pipeline.models)
    pipeline = ScalingPipeline(replace(cfg.pipeline, models=models))
    run = pipeline.run(bundle, progress=progress, prepared=prepared)
    save_run(run, out / "run", rerun=rerun)
    seconds["fit"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    sensitivity = reference_sensitivity(bundle, pipeline.config, cfg.reference_draws, progress)
    sensitivity.to_csv(out / "reference_sensitivity.csv", index=False)
    seconds["reference_sensitivity"] = time.perf_counter() - t0
    figures = make_figures(run, grid, out / "figures")
    if rerun:
        from scaling.runs.rerun_log import log_figures

        log_figures(figures, out / "figures" / "figures.rrd")
    data_summary = pd.concat([summary(train).assign(split="train"), summary(held).assign(split="held out")])
    result = ReproduceResult(out, run, grid, sensitivity, figures, seconds, data_summary)
    write_json(out / "timings.json", seconds)
    write_json(out / "provenance.json", provenance("reproduction", asdict(cfg), cfg.pipeline.seed, bundle.hashes,
                                                   timings=seconds, best_ffnn=best))
    return result


def reference_sensitivity(bundle: DataBundle, config: PipelineConfig, draws: int,
                          progress: bool = False) -> pd.DataFrame:
    """Miniature mean absolute errors of FFNN and direct-Pi refitted with ``draws`` seeded reference rows."""
    rows = []
    names = [n for n in ("ffnn", "ffnn-pose", "direct-pi") if any(s.name == n for s in config.models)]
    for k in range(draws):
        cfg = replace(config, models=model_specs(names, config.models), reference_seed=k)
        res = ScalingPipeline(cfg).run(DataBundle(bundle.train, None, dict(bundle.hashes)), progress=progress)
        ref = res.reference
        row = {"reference_seed": k, "reference_index": ref.name, "reference_pi1": float(ref["F21"] / ref["F31"])}
        row.update({f"{n}_mean_abs_pct_error": res.mini.mean_abs(n) for n in res.mini.predicted})
        if "ffnn" in res.mini.predicted:
            row["reduction"] = res.mini.reduction("ffnn")
        rows.append(row)
    return pd.DataFrame(rows)


def make_figures(run: PipelineResult, grid: pd.DataFrame, fig_dir: str | Path) -> dict[str, Path]:
    """Our versions of the paper's Figs. 6–10 and 12 as PNG files (held-out dig cycles for Figs. 6–7)."""
    fig_dir = Path(fig_dir)
    out: dict[str, Path] = {}
    titles = {"ffnn": "Fig. 6: FFNN, Eq. (10)", "ffnn-pose": "FFNN, Eq. (10) + pose (ours)",
              "gru-eq10": "Fig. 7 (left): GRU, Eq. (10)",
              "gru-eq23": "Fig. 7 (right): GRU, Eq. (23)"}
    for name, title in titles.items():
        if name not in run.models:
            continue
        spec = next(s for s in run.config.models if s.name == name)
        test, kinds = run.test_sets[spec.groups], run.test_kinds[spec.groups]
        dig = test.subset(np.flatnonzero(kinds == "dig")) if np.any(kinds == "dig") else test
        out[name] = Path(fig_dir / f"pred_vs_actual_{name}.png")
        plots.plot_predicted_vs_actual(dig.delta, run.models[name].predict(dig), out[name],
                                       title=f"{title}\nheld-out dig cycles")
    if len(grid):
        out["grid_heatmap"] = fig_dir / "grid_heatmap.png"
        plots.plot_grid_heatmap(grid, out["grid_heatmap"])
        out["grid_landscape"] = fig_dir / "grid_landscape.png"
        plots.plot_grid_landscape(grid, out["grid_landscape"])
        out["r2_vs_units"] = fig_dir / "r2_vs_units.png"
        plots.plot_r2_vs_units(grid, out["r2_vs_units"])
    out["error_vs_load"] = fig_dir / "error_vs_load.png"
    plots.plot_mini_validation(run.mini, out["error_vs_load"])
    return out
