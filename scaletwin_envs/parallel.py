"""The one seam where work fans out: local processes by default, a distributed engine when plugged in.

Sweeps (datasets, grid searches) hand a picklable function and a list of task arguments to an
:class:`Executor`. Results come back as an iterator in completion order, each tagged with its task
index, so callers can persist every finished task at once (nothing is lost on interruption).

Plugging in Ray (or Dask, …) means writing one class with the same ``map_unordered`` method; nothing
else in scaletwin changes. :class:`RayExecutor` is that class, imported lazily.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from typing import Any, Protocol, TypeVar

T = TypeVar("T")
R = TypeVar("R")


class Executor(Protocol):
    """Runs ``fn(task)`` for every task; yields ``(index, result)`` as each finishes."""

    def map_unordered(self, fn: Callable[[T], R], tasks: Sequence[T]) -> Iterator[tuple[int, R]]: ...


class SerialExecutor:
    """Runs tasks one after another in this process (deterministic order; easiest to debug)."""

    def map_unordered(self, fn: Callable[[T], R], tasks: Sequence[T]) -> Iterator[tuple[int, R]]:
        for i, task in enumerate(tasks):
            yield i, fn(task)


class LocalProcessExecutor:
    """Runs tasks in ``workers`` local processes (spawned, so MuJoCo and torch start clean in each)."""

    def __init__(self, workers: int | None = None) -> None:
        if workers is not None and workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.workers = workers or max(1, os.cpu_count() or 1)

    def map_unordered(self, fn: Callable[[T], R], tasks: Sequence[T]) -> Iterator[tuple[int, R]]:
        if self.workers == 1 or len(tasks) <= 1:
            yield from SerialExecutor().map_unordered(fn, tasks)
            return
        with ProcessPoolExecutor(max_workers=self.workers, mp_context=get_context("spawn"),
                                 initializer=_single_threaded_worker) as pool:
            futures = {pool.submit(fn, task): i for i, task in enumerate(tasks)}
            try:
                for fut in as_completed(futures):
                    yield futures[fut], fut.result()
            except BaseException:
                for fut in futures:
                    fut.cancel()
                raise


class RayExecutor:
    """Runs tasks as Ray remote functions (``pip install ray``; ``ray.init`` is the caller's choice)."""

    def __init__(self, **remote_options: Any) -> None:
        try:
            import ray  # noqa: F401
        except ImportError as exc:  # pragma: no cover - optional engine
            raise ImportError("RayExecutor needs the 'ray' package: pip install ray") from exc
        self.remote_options = remote_options

    def map_unordered(self, fn: Callable[[T], R], tasks: Sequence[T]) -> Iterator[tuple[int, R]]:  # pragma: no cover
        import ray

        remote = ray.remote(**self.remote_options)(fn) if self.remote_options else ray.remote(fn)
        refs = {remote.remote(task): i for i, task in enumerate(tasks)}
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            yield refs[done[0]], ray.get(done[0])


def make_executor(spec: str | int | Executor | None = None) -> Executor:
    """``None``/``"local"``: all cores; an int: that many processes; ``"serial"``; ``"ray"``; or an Executor."""
    if spec is None or spec == "local":
        return LocalProcessExecutor()
    if isinstance(spec, int):
        return LocalProcessExecutor(spec) if spec > 1 else SerialExecutor()
    if spec == "serial":
        return SerialExecutor()
    if spec == "ray":
        return RayExecutor()
    if isinstance(spec, str):
        raise ValueError(f"unknown executor {spec!r}; use 'local', 'serial', 'ray', a worker count or an Executor")
    return spec


def _single_threaded_worker() -> None:
    # Several processes each using every core for BLAS/torch would oversubscribe the machine.
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:  # pragma: no cover - torch is a dependency, but workers may not need it
        pass

