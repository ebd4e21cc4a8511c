"""Fit cost of the δ1 models on the standard data set: one FFNN fit and the default 48-configuration grid, timed
side by side with the direct Buckingham-Pi baseline (δ1 ≡ 1, nothing to fit).

Targets (issue 5): one FFNN fit ≤ 60 s and the default grid ≤ 15 min on 2 CPU cores. The grid runs through the
executor seam with ``--workers`` processes (one torch thread each); the single fits use one torch thread.

Run: ``python benchmarks/scaling_fit.py [--data DIR] [--workers 2] [--out benchmarks/results/scaling_fit.md]``.
``--data`` is a folder of recordings of the standard preset (simulated there first if missing).
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from scaletwin_envs.host import host_line
from scaling.data.recordings import STANDARD, dataset_hash, load_or_generate
from scaling.evaluation import metrics as ev
from scaling.models import DirectPi
from scaling.models.grid import DEFAULT_GRID, GridSearch, best_config
from scaling.runs.pipeline import FFNN_CONFIG, PipelineConfig, ScalingPipeline, model_specs
from scaling.runs.provenance import code_version, versions


def timed(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> tuple[Any, float]:
    """(result, wall seconds) of ``fn(*args, **kwargs)``."""
    start = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - start


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(tempfile.gettempdir()) / "scaletwin-bench-standard")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default="benchmarks/results/scaling_fit.md")
    args = ap.parse_args()
    torch.set_num_threads(1)
    load_start = os.getloadavg()[0]
    frame, data_s = timed(load_or_generate, args.data, STANDARD, "serial", False)
    config = PipelineConfig(models=model_specs(["ffnn", "ffnn-pose", "direct-pi"]))
    pipeline = ScalingPipeline(config)
    prep, prep_s = timed(pipeline.prepare, frame)
    train, test = prep.sets["eq10"]
    direct, direct_s = timed(DirectPi(rel_eps=config.rel_eps).fit, train)
    ffnn_spec = model_specs(["ffnn"])[0]
    ffnn, ffnn_s = timed(ffnn_spec.build(rel_eps=config.rel_eps, seed=0, threads=1).fit, train)
    pose_spec = model_specs(["ffnn-pose"])[0]
    pose_train, pose_test = prep.sets[pose_spec.groups]
    posed, pose_s = timed(pose_spec.build(rel_eps=config.rel_eps, seed=0, threads=1).fit, pose_train)
    kinds = ev.kinds_of(test, prep.frame)
    r2 = {name: ev.delta_metrics(model, test, kinds) for name, model in (("direct", direct), ("ffnn", ffnn))}
    r2["ffnn-pose"] = ev.delta_metrics(posed, pose_test, ev.kinds_of(pose_test, prep.frame))
    grid_train, grid_val = train.split_by_episode(0.2, 0)
    base = {k: v for k, v in FFNN_CONFIG.items() if k not in DEFAULT_GRID} | {"rel_eps": config.rel_eps, "seed": 0,
                                                                                "threads": 1}
    search = GridSearch(DEFAULT_GRID, base, "FFNN", args.workers, None, progress=True)
    grid, grid_s = timed(search.run, grid_train, grid_val)
    direct_grid, direct_grid_s = timed(lambda: [DirectPi().fit(grid_train).score(grid_val)
                                                for _ in range(len(grid))])
    best = best_config(grid)
    n = len(grid)
    lines = [f"# scaling_fit ({dt.date.today()}, {host_line()})", "",
             f"Code `{code_version()}`; {versions()}.", "",
             f"Standard data set: {len(frame)} rows ({frame['episode'].nunique()} episodes, hash "
             f"`{dataset_hash(frame)}`), {len(train)} training and {len(test)} held-out δ1 pairs after the domain "
             f"filter; loading {data_s:.1f} s, groups + reference + split {prep_s:.1f} s.", "",
             "| task | configurations | wall [s] | per configuration [s] | limit | met | held-out R² of δ1 "
             "(dig cycles / all rows) |", "|---|---|---|---|---|---|---|",
             f"| direct-Pi fit (δ1 ≡ 1) | 1 | {direct_s:.4f} | {direct_s:.4f} | - | - | "
             f"{r2['direct']['r2_dig']:.4f} / {r2['direct']['r2']:.4f} |",
             f"| FFNN fit ({ffnn_spec.config['hidden_layers']}×{ffnn_spec.config['units']}, 1 thread, "
             f"{ffnn.log_.epochs_run} epochs) | 1 | {ffnn_s:.1f} | {ffnn_s:.1f} | 60 s | "
             f"{'yes' if ffnn_s <= 60 else 'no'} | {r2['ffnn']['r2_dig']:.4f} / {r2['ffnn']['r2']:.4f} |",
             f"| FFNN fit on Eq. (10) + pose (`ffnn-pose`, 1 thread, {posed.log_.epochs_run} epochs) | 1 | "
             f"{pose_s:.1f} | {pose_s:.1f} | 60 s | {'yes' if pose_s <= 60 else 'no'} | "
             f"{r2['ffnn-pose']['r2_dig']:.4f} / {r2['ffnn-pose']['r2']:.4f} |",
             f"| direct-Pi over the grid's validation split | {n} | {direct_grid_s:.3f} | {direct_grid_s / n:.4f} | - "
             f"| - | all rows {direct_grid[0]:.4f} (validation) |",
             f"| FFNN default grid, {args.workers} worker processes | {n} | {grid_s:.0f} | {grid_s / n:.1f} | 900 s | "
             f"{'yes' if grid_s <= 900 else 'no'} | best all rows {grid['r2'].max():.4f} (validation) |", "",
             f"Best grid configuration: hidden_layers={best['hidden_layers']}, units={best['units']}, "
             f"dropout={best['dropout']}, lr={best['lr']}. Mean fit time per configuration in the workers: "
             f"{grid['fit_s'].mean():.1f} s (min {grid['fit_s'].min():.1f}, max {grid['fit_s'].max():.1f}).",
             f"Machine load average (1 min) {load_start:.1f} at the start and {os.getloadavg()[0]:.1f} at the end "
             "(other jobs share the cores when it is above 2).", ""]
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
