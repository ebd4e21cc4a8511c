"""Threads for the batch path: chunks of rows (or groups of sequences) run on every usable core at once.

Torch and NumPy release the GIL inside their kernels, so plain threads scale on the heavy parts (matmuls,
activations, ``arcsinh``/``exp`` over a chunk) while the Python glue between them stays cheap next to a chunk's
work. Inside a parallel section torch's own intra-op pool is held at one thread so that ``threads`` Python threads
use ``threads`` cores, not ``threads²``; the previous setting is restored afterwards.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import TypeVar

import torch

T = TypeVar("T")
R = TypeVar("R")


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the OS reports one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # macOS, Windows
        return max(1, os.cpu_count() or 1)


def resolve_threads(threads: int | None) -> int:
    """``threads`` checked, or every usable core when ``None``.

    Raises:
        ValueError: ``threads`` < 1.
    """
    if threads is None:
        return usable_cores()
    if int(threads) < 1:
        raise ValueError(f"threads must be ≥ 1, got {threads}")
    return int(threads)


@contextmanager
def single_threaded_torch() -> Iterator[None]:
    """Hold torch's intra-op pool at one thread for the duration (the caller parallelises instead)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def map_ordered(fn: Callable[[T], R], items: Sequence[T], threads: int) -> list[R]:
    """``[fn(i) for i in items]``, run on ``threads`` threads when there is more than one item; order kept.

    An exception raised by ``fn`` propagates to the caller unchanged (the first one in ``items`` order).
    """
    if threads <= 1 or len(items) <= 1:
        return [fn(i) for i in items]
    with single_threaded_torch(), ThreadPoolExecutor(max_workers=min(threads, len(items))) as pool:
        return list(pool.map(fn, items))


__all__ = ["map_ordered", "resolve_threads", "single_threaded_torch", "usable_cores"]
