"""The search budget of one diagnosis: a deterministic cap on twin replays and a wall-clock safety net.

The replay cap (:data:`REPLAYS`) is what bounds a diagnosis: every search stops at a batch boundary once it is
spent, so the same recording and seed always give the same answer (~0.1–0.13 s of wall time per replay on 2 cores
with ``workers=2``; the benchmark's diagnoses took a median of 1–2 minutes, up to several on a loaded machine, the
start fit of a log without seed included). The wall-clock limit (:data:`SECONDS`, counted from the start of the
diagnosis) is only a safety net against a replay that hangs: when it cuts the search the result depends on the
machine, and the report says so (:attr:`Budget.cut`). It was 45 s until the twentieth session, which cut the
search on any loaded machine (a CI run beside a benchmark: a soil cohesion fitted 17 % off, cut at 46 s after 70
replays), so that a user's default answer was not the benchmark's (run with 900 s). A batch already started is
finished (a few seconds at most after the first round's screening), and the judgement of a round's winner always
runs.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

#: Twin replays (all of them: nominal, null runs, searches) after which the searches stop.
REPLAYS = 350
#: Seconds from the start of the diagnosis after which identification stops (safety net; fit and compare follow).
SECONDS = 900.0
#: A further selection round starts only with at least this many replays left (screening, refinement, judging).
ROUND_RESERVE = 60


@dataclass
class Budget:
    """Replay and wall-clock limits of the identification; ``spent`` counts the replays so far."""

    replays: int = REPLAYS
    seconds: float = SECONDS
    spent: Callable[[], int] = lambda: 0
    start: float = field(default_factory=time.perf_counter)
    cut: str | None = None  # "replays" or "time" once a search was stopped short
    cut_at: float | None = None  # seconds since the start when that happened

    def elapsed(self) -> float:
        """Seconds since the diagnosis started."""
        return time.perf_counter() - self.start

    def left(self) -> int:
        """Replays left (negative when overspent by a batch that had already started)."""
        return self.replays - self.spent()

    def exhausted(self, reserve: int = 0) -> bool:
        """True (and remembered in :attr:`cut`) when fewer than ``reserve`` replays or no time is left."""
        if self.left() <= reserve:
            self._mark("replays")
            return True
        if self.elapsed() >= self.seconds:
            self._mark("time")
            return True
        return False

    def _mark(self, why: str) -> None:
        if self.cut is None:
            self.cut, self.cut_at = why, self.elapsed()

    def to_dict(self) -> dict[str, Any]:
        """JSON form: limits, what was used, and what cut the search (null: it ran to completion)."""
        return {"replay_budget": int(self.replays), "time_budget_s": float(self.seconds),
                "replays": int(self.spent()), "cut": self.cut,
                "cut_at_s": None if self.cut_at is None else float(self.cut_at)}
