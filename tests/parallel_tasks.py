"""Picklable module-level task functions for the executor tests (local processes and Ray workers import this
module, so it imports nothing heavy at module level)."""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any


def marked_sleep(job: tuple[str, int, float]) -> int:
    """Sleep ``seconds`` (s), writing ``<folder>/start-<i>`` (holding the pid) before and ``<folder>/end-<i>`` after;
    returns ``i``."""
    folder, i, seconds = job
    Path(folder, f"start-{i}").write_text(str(os.getpid()))
    time.sleep(seconds)
    Path(folder, f"end-{i}").write_text("")
    return i


class SlowScripted:
    """The scripted dig, waiting ``delay`` s before every action (to interrupt a sweep mid-way)."""

    def __init__(self, delay: float) -> None:
        from scaletwin_envs.policies import ScriptedDigPolicy

        self.policy, self.delay = ScriptedDigPolicy(), delay

    def reset(self) -> None:
        self.policy.reset()

    def __call__(self, obs: Any) -> Any:
        time.sleep(self.delay)
        return self.policy.act(obs)


def slow_scripted(delay: float = 0.0) -> SlowScripted:
    """Policy factory of :class:`SlowScripted` (for ``SweepSpec(policy="tests.parallel_tasks:slow_scripted")``)."""
    return SlowScripted(delay)


def interrupt_main_when(condition: Callable[[], bool], timeout: float = 60.0) -> threading.Thread:
    """Send SIGINT (what Ctrl-C sends) to the main thread once ``condition()`` holds."""

    def watch() -> None:
        end = time.monotonic() + timeout
        while not condition() and time.monotonic() < end:
            time.sleep(0.01)
        signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return thread
