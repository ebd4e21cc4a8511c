"""Grid search (executor seam, CSV, resume) and the paper's figures."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from matplotlib.figure import Figure

import scaling.models.grid as grid_mod
from scaling.data.delta_dataset import DeltaDataset
from scaling.models.grid import DEFAULT_GRID, GridSearch, best_config, config_key, expand_grid
from scaling.runs.plots import (
    plot_error_vs_load,
    plot_grid_heatmap,
    plot_grid_landscape,
    plot_predicted_vs_actual,
    plot_r2_vs_units,
)
from tests.scaling.test_factors import INPUTS, PI1, synthetic_recordings

torch.set_num_threads(1)
TINY = {"hidden_layers": (1,), "units": (4, 8), "dropout": (0.0,), "lr": (1e-2,)}
BASE = {"epochs": 20, "threads": 1}
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def split() -> tuple[DeltaDataset, DeltaDataset]:
    rec = synthetic_recordings(episodes=(4, 4), steps=30, seed=1)
    return DeltaDataset.from_recordings(rec, PI1, INPUTS).split_by_episode(0.25)


def test_default_grid_has_at_least_48_unique_configs() -> None:
    configs = expand_grid(DEFAULT_GRID)
    assert len(configs) >= 48
    assert len({config_key(c) for c in configs}) == len(configs)
    assert set(configs[0]) == {"hidden_layers", "units", "dropout", "lr"}
    assert "48 configurations" in GridSearch().describe()


def test_grid_search_scores_writes_and_resumes(split: tuple[DeltaDataset, DeltaDataset], tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    csv = tmp_path / "grid.csv"
    search = GridSearch(grid=TINY, base_config=BASE, executor="serial", results_path=csv, progress=False)
    results = search.run(*split)
    assert list(results["units"]) == [4, 8] and np.isfinite(results["r2"]).all()
    assert {"r2", "r2_train", "fit_s", "epochs_run", "config"} <= set(results.columns)
    assert len(pd.read_csv(csv)) == 2
    assert best_config(results)["units"] in (4, 8) and best_config(results)["epochs"] == 20

    def no_refit(task: grid_mod.GridTask) -> dict:
        raise AssertionError(f"config {task.params} was already done")

    monkeypatch.setattr(grid_mod, "evaluate_config", no_refit)
    resumed = search.run(*split)
    pd.testing.assert_frame_equal(resumed, pd.read_csv(csv))
    np.testing.assert_allclose(resumed["r2"], results["r2"])


def test_grid_search_runs_only_missing_configs(split: tuple[DeltaDataset, DeltaDataset], tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    csv = tmp_path / "grid.csv"
    GridSearch(grid={**TINY, "units": (4,)}, base_config=BASE, results_path=csv, progress=False).run(*split)
    calls: list[dict] = []
    original = grid_mod.evaluate_config

    def counting(task: grid_mod.GridTask) -> dict:
        calls.append(task.params)
        return original(task)

    monkeypatch.setattr(grid_mod, "evaluate_config", counting)
    results = GridSearch(grid=TINY, base_config=BASE, results_path=csv, progress=False).run(*split)
    assert [c["units"] for c in calls] == [8]
    assert list(results["units"]) == [4, 8] and len(pd.read_csv(csv)) == 2


def test_grid_search_through_local_processes(split: tuple[DeltaDataset, DeltaDataset]) -> None:
    """Two worker processes give the serial search's table, value by value (seeded fits, one thread each)."""
    grid = {**TINY, "units": (4, 8, 16)}
    base = {"epochs": 5, "threads": 1}
    results = GridSearch(grid=grid, base_config=base, executor=2, progress=False).run(*split)
    serial = GridSearch(grid=grid, base_config=base, executor="serial", progress=False).run(*split)
    assert list(results["units"]) == [4, 8, 16] and np.isfinite(results["r2"]).all()
    assert list(results.columns) == list(serial.columns)
    pd.testing.assert_frame_equal(results.drop(columns="fit_s"), serial.drop(columns="fit_s"), check_exact=True)


def test_figures_are_written(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    actual = rng.uniform(0.5, 2.0, 200)
    fig = plot_predicted_vs_actual(actual, actual * rng.normal(1, 0.01, 200), tmp_path / "pva.png")
    assert isinstance(fig, Figure) and "R² = 0.99" in fig.axes[0].get_title()
    results = pd.DataFrame([{**c, "r2": 0.9 - 0.1 * c["dropout"] + 0.001 * c["units"]}
                            for c in expand_grid(DEFAULT_GRID)])
    paths = [tmp_path / n for n in ("heat.png", "land.png", "units.png", "load.png")]
    figs = [plot_grid_heatmap(results, paths[0]), plot_grid_landscape(results, paths[1]),
            plot_r2_vs_units(results, paths[2]),
            plot_error_vs_load(np.linspace(0.5, 4, 8), {"FFNN": np.full(8, 4.3), "DirectPi": np.full(8, 42.0)},
                               paths[3])]
    assert all(isinstance(f, Figure) for f in figs)
    for p in [tmp_path / "pva.png", *paths]:
        assert p.read_bytes()[:8] == PNG
    assert json.loads(config_key({"b": 1, "a": 0.5})) == {"a": 0.5, "b": 1}
