"""Which explanations a recording cannot tell apart, and which channel would.

Friction in a cylinder and at the hinge it drives act on the same motion; on many recordings they fit equally
well. A rival whose objective is within :data:`INDISTINGUISHABLE` of the winner's (the objective is −2 log
likelihood in whitened units, so that is a likelihood ratio under e³ ≈ 20) is reported as an alternative rather
than silently beaten. For each, the channel where the two corrected twins differ most (in units of that channel's
noise; 1 % of its spread for a channel the log does not have) is the one that would separate them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from discrepancy.context import Context
from discrepancy.data.channels import COMPARED
from discrepancy.effects import Effect

INDISTINGUISHABLE = 6.0  # objective difference (whitened, −2 log likelihood) below which two fits are not told apart
UNLOGGED_NOISE = 0.01  # noise assumed on a channel the log lacks, as a fraction of the twin's spread


@dataclass(frozen=True)
class Alternative:
    """A rival explanation: its label, its objective above the winner's, the separating channel and whether the
    log has it, and how far apart the two fits are on that channel (RMS, noise units)."""

    label: str
    delta_objective: float
    channel: str
    in_log: bool
    separation: float

    def to_dict(self) -> dict[str, object]:
        return {"label": self.label, "delta_objective": self.delta_objective, "channel": self.channel,
                "in_log": self.in_log, "separation": self.separation}


def alternatives(ctx: Context, base: Sequence[Effect], winner: Effect, winner_cost: float,
                 rivals: Sequence[tuple[Effect, float]]) -> list[Alternative]:
    """The rivals (effect, objective) the recording cannot tell from ``winner`` on top of ``base``."""
    close = [(e, c) for e, c in rivals if c - winner_cost <= INDISTINGUISHABLE and e.label() != winner.label()]
    if not close:
        return []
    assert ctx.noise is not None
    won = ctx.replays.get([*base, winner]).signals
    nominal = ctx.nominal.signals
    out = []
    for effect, cost in close:
        other = ctx.replays.get([*base, effect]).signals
        best, best_score = "", -1.0
        for s in COMPARED:
            if s not in won or s not in other:
                continue
            diff = won[s] - other[s]
            if s in ctx.names:
                scale = ctx.noise.total[:, ctx.names.index(s)]
            else:
                scale = UNLOGGED_NOISE * max(float(np.nanmax(nominal[s]) - np.nanmin(nominal[s])), 1e-12)
            score = float(np.sqrt(np.nanmean((diff / scale) ** 2)))
            if np.isfinite(score) and score > best_score:
                best, best_score = s, score
        out.append(Alternative(effect.label(), float(cost - winner_cost), best, best in ctx.names, best_score))
    return out
