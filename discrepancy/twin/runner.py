"""Running many twin replays: in this process (:class:`SerialRunner`) or in a persistent pool of worker processes
(:class:`PoolRunner`), behind one ``run_many`` method, with results cached by planted effects.

Workers are spawned once and keep their own :class:`~discrepancy.twin.spec.Simulator` per twin, so a batch costs only
the replays. Results come back in the order of the requests, so everything stays deterministic.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from typing import Protocol

import numpy as np

from discrepancy.effects import Effect
from discrepancy.twin.plant import Plan, apply_sensors, plan
from discrepancy.twin.spec import SimResult, Simulator, TwinSpec


class Runner(Protocol):
    """Replays ``commands`` once per plan."""

    twin: TwinSpec

    def run_many(self, commands: np.ndarray, plans: Sequence[Plan], seed: int | None = None) -> list[SimResult]: ...

    def close(self) -> None: ...


class SerialRunner:
    """Replays in this process."""

    def __init__(self, twin: TwinSpec) -> None:
        self.twin = twin
        self.sims = {twin.seed: Simulator(twin)}

    @property
    def sim(self) -> Simulator:
        return self.sims[self.twin.seed]

    def run_many(self, commands: np.ndarray, plans: Sequence[Plan], seed: int | None = None) -> list[SimResult]:
        seed = self.twin.seed if seed is None else seed
        if seed not in self.sims:
            self.sims[seed] = Simulator(dataclasses.replace(self.twin, seed=seed))
        return [self.sims[seed].run(commands, p) for p in plans]

    def close(self) -> None:
        """Nothing to release."""


_WORKER_SIMS: dict[str, Simulator] = {}


def _replay_task(task: tuple[TwinSpec, np.ndarray, Plan]) -> SimResult:
    twin, commands, p = task
    key = repr(twin)
    if key not in _WORKER_SIMS:
        if len(_WORKER_SIMS) > 4:
            _WORKER_SIMS.clear()
        _WORKER_SIMS[key] = Simulator(twin)
    return _WORKER_SIMS[key].run(commands, p)


def _init_worker() -> None:
    os.environ.setdefault("OMP_NUM_THREADS", "1")


class PoolRunner:
    """Replays in ``workers`` spawned processes (kept alive until :meth:`close`)."""

    def __init__(self, twin: TwinSpec, workers: int = 2) -> None:
        if workers < 2:
            raise ValueError(f"PoolRunner needs workers >= 2 (use SerialRunner), got {workers}")
        self.twin = twin
        self.pool = ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn"),
                                        initializer=_init_worker)

    def run_many(self, commands: np.ndarray, plans: Sequence[Plan], seed: int | None = None) -> list[SimResult]:
        twin = self.twin if seed is None else dataclasses.replace(self.twin, seed=seed)
        return list(self.pool.map(_replay_task, [(twin, commands, p) for p in plans]))

    def close(self) -> None:
        self.pool.shutdown(cancel_futures=True)


def make_runner(twin: TwinSpec, workers: int = 1) -> Runner:
    """A serial runner for ``workers`` ≤ 1, else a process pool."""
    return SerialRunner(twin) if workers <= 1 else PoolRunner(twin, workers)


class CachedReplays:
    """Replays of one recording's commands with sets of effects, cached by the physics effects; sensor effects
    are applied on top of a cached replay (they change no physics, so they cost no simulation)."""

    def __init__(self, runner: Runner, commands: np.ndarray, time: np.ndarray, seed: int | None = None) -> None:
        self.runner, self.commands, self.time, self.seed = runner, commands, time, seed
        self.cache: dict[tuple[Effect, ...], SimResult] = {}
        self.runs = 0

    def get_many(self, effect_sets: Sequence[Sequence[Effect]]) -> list[SimResult]:
        split = [_split(e) for e in effect_sets]
        todo = list(dict.fromkeys(k for k, _ in split if k not in self.cache))
        if todo:
            soil = self.runner.twin.soil
            results = self.runner.run_many(self.commands, [plan(k, soil) for k in todo], self.seed)
            self.cache.update(zip(todo, results, strict=True))
            self.runs += len(todo)
        out = []
        for key, sensors in split:
            r = self.cache[key]
            out.append(r if not sensors else SimResult(apply_sensors(r.signals, self.time, sensors), r.phases, r.error))
        return out

    def get(self, effects: Sequence[Effect]) -> SimResult:
        return self.get_many([effects])[0]


def _split(effects: Sequence[Effect]) -> tuple[tuple[Effect, ...], list[Effect]]:
    physics = tuple(e for e in effects if e.spec.plant != "sensor")
    return physics, [e for e in effects if e.spec.plant == "sensor"]
