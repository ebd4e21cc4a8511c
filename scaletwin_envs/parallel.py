"""The one seam where work fans out: local processes by default, Ray when asked for.

Sweeps (datasets, grid searches, replays) hand a picklable function and a list of task arguments to an
:class:`Executor`. Results come back as an iterator in completion order, each tagged with its task index, so callers
can persist every finished task at once. :func:`map_in_order` collects them in task order instead.

Interruption (``KeyboardInterrupt``, i.e. Ctrl-C, while the iterator waits): every task not finished is cancelled
(queued ones never start, running ones are stopped), the results that had already finished are still yielded, and
then the ``KeyboardInterrupt`` is raised again. Closing the iterator early (``break``, an exception in the caller's
loop) cancels the outstanding tasks too. An exception raised by a task is raised from the iterator, after the other
tasks are cancelled.

Plugging in another engine (Dask, …) means writing one class with the same ``map_unordered`` method; nothing else in
scaletwin changes. :class:`RayExecutor` is that class for Ray (``pip install "scaletwin[ray]"``), imported lazily.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor
from concurrent.futures import wait as futures_wait
from multiprocessing import get_context
from typing import Any, Protocol, TypeVar

T = TypeVar("T")
R = TypeVar("R")

#: Seconds between checks while waiting for results: the longest an interrupt waits to be noticed on platforms
#: where a blocked wait is not woken by the signal itself.
POLL_S = 0.25


class Executor(Protocol):
    """Runs ``fn(task)`` for every task; yields ``(index, result)`` as each finishes."""

    def map_unordered(self, fn: Callable[[T], R], tasks: Sequence[T]) -> Iterator[tuple[int, R]]: ...


def map_in_order(fn: Callable[[T], R], tasks: Sequence[T],
                 executor: str | int | Executor | None = "serial") -> list[R]:
    """``[fn(task) for task in tasks]`` through an executor: results in task order, whatever order they finish in.

    Args:
        fn: a module-level function (picklable: it travels to worker processes or Ray workers).
        tasks: its arguments, one task each (picklable).
        executor: anything :func:`make_executor` accepts (default serial).

    Raises:
        KeyboardInterrupt: interrupted; the outstanding tasks are cancelled.
        Exception: the first task error to arrive; the outstanding tasks are cancelled.
    """
    results: dict[int, R] = {}
    for i, result in make_executor(executor).map_unordered(fn, tasks):
        results[i] = result
    return [results[i] for i in range(len(tasks))]


class SerialExecutor:
    """Runs tasks one after another in this process (deterministic order; easiest to debug)."""

    def map_unordered(self, fn: Callable[[T], R], tasks: Sequence[T]) -> Iterator[tuple[int, R]]:
        for i, task in enumerate(tasks):
            yield i, fn(task)


class LocalProcessExecutor:
    """Runs tasks in ``workers`` local processes (spawned, so MuJoCo and torch start clean in each; one torch/BLAS
    thread per process). An interrupt terminates the worker processes, which stops the running tasks."""

    def __init__(self, workers: int | None = None, persistent: bool = False) -> None:
        if workers is not None and workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.workers = workers or max(1, os.cpu_count() or 1)
        self.persistent = persistent  # keep the worker processes (and what they cached) between calls
        self._pool: ProcessPoolExecutor | None = None

    def _new_pool(self, tasks: int) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(max_workers=self.workers if self.persistent else min(self.workers, tasks),
                                   mp_context=get_context("spawn"), initializer=_set_worker_threads, initargs=(1,))

    def close(self) -> None:
        """Stop a persistent pool's workers (nothing to do otherwise)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def map_unordered(self, fn: Callable[[T], R], tasks: Sequence[T]) -> Iterator[tuple[int, R]]:
        if self.workers == 1 or (len(tasks) <= 1 and not self.persistent):
            yield from SerialExecutor().map_unordered(fn, tasks)
            return
        if self.persistent:
            self._pool = self._pool or self._new_pool(len(tasks))
            pool = self._pool
        else:
            pool = self._new_pool(len(tasks))
        index: dict[Future[R], int] = {pool.submit(fn, task): i for i, task in enumerate(tasks)}
        pending: set[Future[R]] = set(index)
        ready: list[Future[R]] = []  # finished, not handed out yet
        completed = False
        try:
            while pending:
                done, pending = futures_wait(pending, timeout=POLL_S, return_when=FIRST_COMPLETED)
                ready = sorted(done, key=index.__getitem__)
                while ready:
                    fut = ready.pop(0)
                    yield index[fut], fut.result()
            completed = True
        except KeyboardInterrupt:
            finished = [f for f in [*ready, *pending] if f.done() and not f.cancelled() and f.exception() is None]
            _stop_pool(pool)
            self._pool = None
            for fut in sorted(finished, key=index.__getitem__):
                yield index[fut], fut.result()
            raise
        finally:
            if not completed:
                _stop_pool(pool)
                self._pool = None
            elif not self.persistent:
                pool.shutdown(wait=True)


class RayExecutor:
    """Runs tasks as Ray tasks, on a local Ray or on a cluster (``pip install "scaletwin[ray]"``).

    Args:
        address: the cluster to connect to when Ray is not initialised yet in this process (``"auto"``, a GCS
            address ``"10.0.0.1:6379"`` or a Ray Client address ``"ray://head:10001"``); ``None`` lets ``ray.init``
            decide (the ``RAY_ADDRESS`` environment variable, else a new local Ray). A Ray already initialised by the
            caller is used as it is.
        num_cpus: CPUs reserved per task (also the torch/BLAS threads of the task; fractions allowed, ≥ 1 thread).
        num_gpus: GPUs reserved per task.
        memory: bytes of memory reserved per task (``None``: no reservation).
        resources: custom Ray resources per task, e.g. ``{"sim_node": 1}``.
        runtime_env: Ray runtime environment for ``ray.init`` (e.g. ``{"pip": ["scaletwin[ray]==0.1.0"]}``), used
            only when this executor initialises Ray.
        init_options: further keyword arguments of ``ray.init`` (same condition).
        remote_options: further options of the Ray task (``max_retries``, ``scheduling_strategy``, …).

    Raises:
        ImportError: Ray is not installed.
        ValueError: a resource amount is negative.
    """

    def __init__(self, address: str | None = None, *, num_cpus: float = 1.0, num_gpus: float = 0.0,
                 memory: int | None = None, resources: Mapping[str, float] | None = None,
                 runtime_env: Mapping[str, Any] | None = None, init_options: Mapping[str, Any] | None = None,
                 **remote_options: Any) -> None:
        try:
            import ray  # noqa: F401
        except ImportError as exc:
            raise ImportError('RayExecutor needs Ray: pip install "scaletwin[ray]"') from exc
        for name, value in (("num_cpus", num_cpus), ("num_gpus", num_gpus), ("memory", memory or 0)):
            if not value >= 0:
                raise ValueError(f"{name} must be >= 0, got {value}")
        self.address = address
        self.num_cpus = float(num_cpus)
        self.runtime_env = dict(runtime_env) if runtime_env else None
        self.init_options = dict(init_options or {})
        self.remote_options: dict[str, Any] = {"num_cpus": self.num_cpus, "num_gpus": float(num_gpus),
                                               **({"memory": memory} if memory else {}),
                                               **({"resources": dict(resources)} if resources else {}),
                                               **remote_options}

    def connect(self) -> Any:
        """Initialise Ray if this process has not (see ``address``); returns the ``ray`` module."""
        import ray

        if not ray.is_initialized():
            options = dict(self.init_options)
            if self.runtime_env:
                options["runtime_env"] = self.runtime_env
            ray.init(address=self.address, **options)
        return ray

    def multi_node(self) -> bool:
        """Whether the cluster has more than one live node (then a local output path is not shared by workers)."""
        ray = self.connect()
        return sum(1 for node in ray.nodes() if node.get("Alive")) > 1

    def map_unordered(self, fn: Callable[[T], R], tasks: Sequence[T]) -> Iterator[tuple[int, R]]:
        if not tasks:
            return
        ray = self.connect()
        threads = max(1, int(self.remote_options.get("num_cpus") or 1))
        remote = ray.remote(_call_in_ray_worker).options(**self.remote_options)
        fn_ref = ray.put(fn)
        index = {remote.remote(fn_ref, task, threads): i for i, task in enumerate(tasks)}
        pending = list(index)
        try:
            while pending:
                done, pending = ray.wait(pending, num_returns=1, timeout=POLL_S)
                for ref in done:
                    yield index[ref], ray.get(ref)
        except KeyboardInterrupt:
            finished, pending = ray.wait(pending, num_returns=len(pending), timeout=0) if pending else ([], [])
            _cancel_ray(ray, pending)
            pending = []
            for ref in sorted(finished, key=index.__getitem__):
                try:
                    result = ray.get(ref)
                except Exception:  # a failed or cancelled task has no result to keep
                    continue
                yield index[ref], result
            raise
        finally:
            _cancel_ray(ray, pending)


def make_executor(spec: str | int | Executor | None = None) -> Executor:
    """``None``/``"local"``: all cores; an int: that many processes; ``"serial"``; ``"ray"`` (Ray with its default
    address and one CPU per task: build a :class:`RayExecutor` for more); or an Executor, returned as it is."""
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


def _call_in_ray_worker(fn: Callable[[T], R], task: T, threads: int) -> R:
    """The Ray task: ``fn(task)`` with ``threads`` torch/BLAS threads, as many as the CPUs reserved for it."""
    _set_worker_threads(threads)
    return fn(task)


def _cancel_ray(ray: Any, refs: Sequence[Any]) -> None:
    for ref in refs:
        with contextlib.suppress(Exception):  # already finished, or the connection is gone: nothing to cancel
            ray.cancel(ref)  # a queued task never starts; a running one gets KeyboardInterrupt


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Cancel queued tasks and terminate the workers (stopping running tasks; their atomic writes leave nothing)."""
    terminate = getattr(pool, "terminate_workers", None)  # Python ≥ 3.14
    if terminate is not None:  # pragma: no cover - newer Python
        pool.shutdown(wait=False, cancel_futures=True)
        terminate()
        return
    processes = list((getattr(pool, "_processes", None) or {}).values())  # shutdown forgets them
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        if process.is_alive():
            process.terminate()
    for process in processes:
        process.join(timeout=5.0)


def _set_worker_threads(threads: int) -> None:
    """One worker's torch/OpenMP threads: several processes each using every core would oversubscribe the machine.

    Sets ``OMP_NUM_THREADS`` (read by torch and OpenMP when they start) and, if torch is already imported, its
    thread count; torch is not imported here (seconds per worker for tasks that never use it).
    """
    os.environ["OMP_NUM_THREADS"] = str(threads)
    torch = sys.modules.get("torch")
    if torch is not None and torch.get_num_threads() != threads:
        torch.set_num_threads(threads)
