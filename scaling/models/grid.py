"""Grid search over δ1 model hyper-parameters, scored by held-out R² of δ1 (paper §2.6, Figs. 8–10).

Every configuration is fitted on the same training episodes and scored on the same held-out episodes. Configurations
run through the executor seam :func:`scaletwin_envs.parallel.make_executor` (serial, local processes or Ray); each
finished configuration is appended to the results CSV at once, and a rerun with the same CSV skips what is done.
"""

from __future__ import annotations

import itertools
import json
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd
from tqdm.auto import tqdm

from scaletwin_envs.parallel import Executor, make_executor
from scaling.data.delta_dataset import DeltaDataset
from scaling.models.base import model_class

#: The paper's four hyper-parameters; 3 × 4 × 2 × 2 = 48 configurations.
DEFAULT_GRID: dict[str, tuple[Any, ...]] = {
    "hidden_layers": (1, 2, 3),
    "units": (8, 16, 32, 64),
    "dropout": (0.0, 0.2),
    "lr": (1e-3, 1e-2),
}

#: Grids at most this long run serially when no executor is given.
SERIAL_MAX = 4


def expand_grid(grid: Mapping[str, Sequence[Any]]) -> list[dict[str, Any]]:
    """Cartesian product of the grid, in a stable order (last key varies fastest)."""
    keys = list(grid)
    return [dict(zip(keys, values, strict=True)) for values in itertools.product(*(grid[k] for k in keys))]


def config_key(config: Mapping[str, Any]) -> str:
    """Canonical JSON of a full model configuration: the identity used to skip finished runs."""
    return json.dumps(dict(config), sort_keys=True)


@dataclass(frozen=True)
class GridTask:
    """One configuration to fit and score (picklable, so it can travel to worker processes)."""

    model: str
    config: dict[str, Any]
    params: dict[str, Any]
    train: DeltaDataset
    test: DeltaDataset


def evaluate_config(task: GridTask) -> dict[str, Any]:
    """Fit ``task.model(**task.config)`` on the training set; return the grid parameters and held-out metrics.

    Returns a row with the grid parameters, ``r2`` (held-out R² of δ1), ``r2_train``, ``fit_s`` (seconds),
    ``epochs_run``/``best_epoch`` (neural models) and ``config`` (canonical JSON of the full configuration).
    """
    model = model_class(task.model)(**task.config)
    start = time.perf_counter()
    model.fit(task.train)
    fit_s = time.perf_counter() - start
    log = getattr(model, "log_", None)
    return {**task.params, "r2": model.score(task.test), "r2_train": model.score(task.train), "fit_s": fit_s,
            "epochs_run": getattr(log, "epochs_run", 0), "best_epoch": getattr(log, "best_epoch", -1),
            "model": task.model, "config": config_key(task.config)}


@dataclass
class GridSearch:
    """Exhaustive search over ``grid`` (model keyword → values) on top of the fixed ``base_config``.

    Args:
        grid: values per hyper-parameter (default :data:`DEFAULT_GRID`, 48 FFNN configurations).
        base_config: keyword arguments shared by every configuration (epochs, batch size, seed, ...).
        model: registered model class name (``"FFNN"``, ``"GRUModel"``, ...).
        executor: anything :func:`make_executor` accepts; ``None`` runs grids of ≤ :data:`SERIAL_MAX` pending
            configurations serially and larger ones in local processes.
        results_path: CSV to append finished rows to and to resume from (optional).
        progress: show a tqdm progress bar.
    """

    grid: Mapping[str, Sequence[Any]] = field(default_factory=lambda: dict(DEFAULT_GRID))
    base_config: Mapping[str, Any] = field(default_factory=dict)
    model: str = "FFNN"
    executor: str | int | Executor | None = None
    results_path: str | Path | None = None
    progress: bool = True

    def configs(self) -> list[dict[str, Any]]:
        return expand_grid(self.grid)

    def describe(self) -> str:
        sizes = " × ".join(f"{k} {list(v)}" for k, v in self.grid.items())
        return (f"GridSearch({self.model}: {len(self.configs())} configurations = {sizes}; "
                f"fixed {dict(self.base_config)}; score = held-out R² of δ1)")

    def run(self, train: DeltaDataset, test: DeltaDataset) -> pd.DataFrame:
        """Fit and score every configuration not already in ``results_path``; all rows, in grid order."""
        done = self._load_done()
        keys_done = set(done["config"]) if not done.empty else set()
        tasks = [GridTask(self.model, {**self.base_config, **p}, p, train, test) for p in self.configs()]
        pending = [t for t in tasks if config_key(t.config) not in keys_done]
        rows = [] if done.empty else done.to_dict("records")
        ex = make_executor(("serial" if len(pending) <= SERIAL_MAX else None) if self.executor is None
                           else self.executor)
        with tqdm(total=len(tasks), initial=len(tasks) - len(pending), desc=f"grid {self.model}",
                  disable=not self.progress) as bar:
            for _, row in ex.map_unordered(evaluate_config, pending):
                rows.append(row)
                self._append(row)
                bar.set_postfix(r2=f"{row['r2']:.3f}")
                bar.update()
        return self._ordered(rows, tasks)

    def run_on(self, dataset: DeltaDataset, test_fraction: float = 0.2, seed: int = 0) -> pd.DataFrame:
        """Split ``dataset`` by episode, then :meth:`run`."""
        return self.run(*dataset.split_by_episode(test_fraction, seed))

    def _load_done(self) -> pd.DataFrame:
        path = None if self.results_path is None else Path(self.results_path)
        if path is None or not path.exists() or path.stat().st_size == 0:
            return pd.DataFrame()
        return pd.read_csv(path)

    def _append(self, row: Mapping[str, Any]) -> None:
        if self.results_path is None:
            return
        path = Path(self.results_path)
        path.parent.mkdir(parents=True, exist_ok=True)
        new = not path.exists() or path.stat().st_size == 0
        frame = pd.DataFrame([row])
        if not new:  # keep the existing column order of a resumed file
            frame = frame.reindex(columns=pd.read_csv(path, nrows=0).columns)
        frame.to_csv(path, mode="a", header=new, index=False)

    @staticmethod
    def _ordered(rows: list[dict[str, Any]], tasks: list[GridTask]) -> pd.DataFrame:
        order = {config_key(t.config): i for i, t in enumerate(tasks)}
        df = pd.DataFrame(rows)
        if df.empty:
            return df
        df["_order"] = df["config"].map(order)
        df = df.sort_values("_order", na_position="last", kind="stable")
        return df.drop(columns="_order").reset_index(drop=True)


def best_config(results: pd.DataFrame) -> dict[str, Any]:
    """The full configuration (decoded JSON) of the row with the highest held-out R²."""
    if results.empty:
        raise ValueError("no results")
    return json.loads(results.loc[results["r2"].idxmax(), "config"])
