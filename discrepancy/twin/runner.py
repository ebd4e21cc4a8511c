"""Running many twin replays: in this process (:class:`SerialRunner`) or through the executor seam of
:mod:`scaletwin_envs.parallel` (:class:`ExecutorRunner`: persistent local processes or Ray), behind one
``run_many`` method, with results cached by planted effects.

Workers keep their own :class:`~discrepancy.twin.spec.Simulator` per twin, so a batch costs only the replays.
Results come back in the order of the requests, so everything stays deterministic.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Protocol

import numpy as np

from discrepancy.effects import Effect
from discrepancy.twin.plant import Plan, apply_sensors, plan
from discrepancy.twin.spec import SimResult, Simulator, TwinSpec
from scaletwin_envs.parallel import Executor, LocalProcessExecutor, make_executor, map_in_order

Start = tuple[tuple[str, float], ...]  # reset options (name, value), see TwinSpec.start


class Runner(Protocol):
    """Replays ``commands`` once per plan."""

    twin: TwinSpec

    def run_many(self, commands: np.ndarray, plans: Sequence[Plan], seed: int | None = None,
                 starts: Sequence[Start] | None = None, between: bool = False) -> list[SimResult]: ...

    def with_twin(self, twin: TwinSpec) -> Runner:
        """This runner's workers replaying ``twin`` (shared; close only the original)."""
        ...

    def close(self) -> None: ...


class SerialRunner:
    """Replays in this process."""

    def __init__(self, twin: TwinSpec, sims: dict[str, Simulator] | None = None) -> None:
        self.twin = twin
        self.sims = sims if sims is not None else {}  # by repr of the twin (its dict fields are not hashable)

    def _sim(self, twin: TwinSpec) -> Simulator:
        key = repr(twin)
        if key not in self.sims:
            self.sims[key] = Simulator(twin)
        return self.sims[key]

    def with_twin(self, twin: TwinSpec) -> SerialRunner:
        return SerialRunner(twin, self.sims)

    def run_many(self, commands: np.ndarray, plans: Sequence[Plan], seed: int | None = None,
                 starts: Sequence[Start] | None = None, between: bool = False) -> list[SimResult]:
        """One replay per plan (and per start, when given: reset options overriding the twin's); with ``between``
        each also read between its control steps (``SimResult.between``)."""
        sim = self._sim(self.twin if seed is None else dataclasses.replace(self.twin, seed=seed))
        starts = starts if starts is not None else [None] * len(plans)
        return [sim.run(commands, p, start=st, between=between) for p, st in zip(plans, starts, strict=True)]

    def close(self) -> None:
        """Nothing to release."""


_WORKER_SIMS: dict[str, Simulator] = {}


def _replay_task(task: tuple[TwinSpec, np.ndarray, Plan, Start | None, bool]) -> SimResult:
    """One replay in a worker, on a :class:`Simulator` the worker keeps per twin (its envs are built once)."""
    twin, commands, p, start, between = task
    key = repr(twin)
    if key not in _WORKER_SIMS:
        if len(_WORKER_SIMS) > 4:
            _WORKER_SIMS.clear()
        _WORKER_SIMS[key] = Simulator(twin)
    return _WORKER_SIMS[key].run(commands, p, start=start, between=between)


class ExecutorRunner:
    """Replays through the executor seam of :mod:`scaletwin_envs.parallel`: persistent local worker processes, or
    Ray (workers keep their simulators between batches either way). Results come back in request order."""

    def __init__(self, twin: TwinSpec, executor: Executor, owned: bool = True) -> None:
        self.twin, self.executor, self.owned = twin, executor, owned

    def run_many(self, commands: np.ndarray, plans: Sequence[Plan], seed: int | None = None,
                 starts: Sequence[Start] | None = None, between: bool = False) -> list[SimResult]:
        twin = self.twin if seed is None else dataclasses.replace(self.twin, seed=seed)
        starts = starts if starts is not None else [None] * len(plans)
        return map_in_order(_replay_task, [(twin, commands, p, st, between)
                                           for p, st in zip(plans, starts, strict=True)], self.executor)

    def with_twin(self, twin: TwinSpec) -> ExecutorRunner:
        return ExecutorRunner(twin, self.executor, owned=False)

    def close(self) -> None:
        close = getattr(self.executor, "close", None)
        if self.owned and close is not None:
            close()


def make_runner(twin: TwinSpec, workers: int = 1, executor: str | Executor | None = None) -> Runner:
    """Serial for ``workers`` ≤ 1 and no ``executor``; else ``workers`` persistent local processes, or the given
    executor (``"ray"``, a :class:`~scaletwin_envs.parallel.RayExecutor`, …)."""
    if executor is not None and executor != "local":
        return ExecutorRunner(twin, make_executor(executor))
    if workers <= 1:
        return SerialRunner(twin)
    return ExecutorRunner(twin, LocalProcessExecutor(workers, persistent=True))


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
