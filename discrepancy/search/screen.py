"""One round of physics candidates: screen every candidate at its catalogue grid, refine the most promising.

Screening is a finite-difference regression: each candidate's signature at a grid magnitude is the change of the
twin's signals it causes (one replay per grid point, on the nominal twin, reused in later rounds). In the first
round a candidate scores the objective of the twin with it. In later rounds the residual of the nominal twin is
regressed jointly on the signature of the effects accepted so far and on the candidate's (robust weights, two
amplitudes), so an accepted effect that absorbed part of the candidate's residual may shrink: the score is what
is left. The best :data:`REFINE` candidates (and every dead time that takes away a good part of the kinematic
residual) are then fitted by re-simulating the twin with them on top of the accepted effects
(:mod:`discrepancy.search.refine`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from discrepancy.context import Context, huber, huber_weights
from discrepancy.effects import Effect
from discrepancy.search.candidates import Candidate, physics_candidates
from discrepancy.search.refine import KINEMATIC, make_search, run_searches

REFINE = 3  # candidates refined per round
LAG_GAIN = 0.75  # a delay candidate is refined too when it removes a quarter of the kinematic residual

Seen = list[tuple[np.ndarray, float, np.ndarray]]  # (u, objective, whitened residual)


@dataclass
class Trial:
    """A fitted candidate: the effect (SI), the objective of the twin with it, and its screening score."""

    effect: Effect
    cost: float
    screen: float = float("inf")


def _evaluate(ctx: Context, base: list[Effect], batch: list[tuple[Candidate, np.ndarray]]
              ) -> list[tuple[float, np.ndarray]]:
    mats = ctx.simulate_many([[*base, c.effect(u, ctx.scales)] for c, u in batch])
    out = []
    for m in mats:
        z = ctx.z(m)
        out.append((float(np.sum(huber(z))), z))
    return out


def _joint_scores(ctx: Context, base: list[Effect], batch: list[tuple[Candidate, np.ndarray]]) -> list[float]:
    """Robust residual of the nominal twin after regressing it on the base's and each candidate's signatures."""
    nominal = ctx.simulate([])
    r = ctx.z(nominal).ravel()
    w = huber_weights(r)
    d_base = (ctx.z(nominal) - ctx.z(ctx.simulate(base))).ravel()  # = whitened change the base causes
    out = []
    for m in ctx.simulate_many([[c.effect(u, ctx.scales)] for c, u in batch]):
        d = np.nan_to_num((ctx.z(nominal) - ctx.z(m)).ravel())
        x = np.stack([d_base, d], axis=1)
        a = x.T @ (w[:, None] * x) + 1e-9 * np.eye(2)
        coef = np.linalg.solve(a, x.T @ (w * r))
        e = r - x @ coef
        out.append(float(np.sum(w * e * e)))
    return out


Scores = dict[Candidate, tuple[float, np.ndarray]]  # best screening score and its grid point


def _screen(ctx: Context, base: list[Effect], cands: list[Candidate]) -> tuple[dict[Candidate, Seen], Scores]:
    """Grid points of every candidate (exact in the first round) and each candidate's screening score."""
    batch = [(c, u) for c in cands for u in c.grid()]
    seen: dict[Candidate, Seen] = {c: [] for c in cands}
    if not base:
        for (c, u), (cost, z) in zip(batch, _evaluate(ctx, base, batch), strict=True):
            seen[c].append((u, cost, z))
        return seen, {c: min(((s[1], s[0]) for s in seen[c]), key=lambda x: x[0]) for c in cands}
    scores: Scores = {}
    for (c, u), score in zip(batch, _joint_scores(ctx, base, batch), strict=True):
        if c not in scores or score < scores[c][0]:
            scores[c] = (score, u)
    return seen, scores


def _lags(ctx: Context, base: list[Effect], seen: Seen) -> bool:
    """Does a delay at some grid point take a good part of the kinematic residual away?"""
    idx = [ctx.names.index(k) for k in KINEMATIC if k in ctx.names]
    if len(idx) < len(KINEMATIC) or not seen:
        return False
    before = float(np.sum(huber(ctx.z(ctx.simulate(base))[:, idx])))
    return min(float(np.sum(huber(z[:, idx]))) for _, _, z in seen) < LAG_GAIN * before


def physics_trials(ctx: Context, base: list[Effect], allows: Callable[[str, str | None], bool],
                   refine: int = REFINE) -> list[Trial]:
    """Every allowed physics candidate not yet accepted, screened; the best ``refine`` fitted by re-simulation."""
    taken = {(e.name, e.target) for e in base}
    cands = [c for c in physics_candidates() if (c.name, c.target) not in taken and allows(c.name, c.target)]
    if not cands:
        return []
    seen, scores = _screen(ctx, base, cands)
    ranked = sorted(cands, key=lambda c: scores[c][0])
    chosen = ranked[:refine]
    if base:  # exact replays, on top of the accepted effects, for the candidates that go on
        batch = [(c, u) for c in ranked if c.name == "actuator_delay" or c in chosen for u in c.grid()]
        for (c, u), res in zip(batch, _evaluate(ctx, base, batch), strict=True):
            seen[c].append((u, *res))
    chosen += [c for c in ranked[refine:] if c.name == "actuator_delay" and _lags(ctx, base, seen[c])]
    searches = [make_search(c, ctx.scales, seen[c], ctx.names, ctx.real.dt) for c in chosen]
    run_searches(searches, lambda b: _evaluate(ctx, base, b), ctx.budget.exhausted)
    vertices = [(s.candidate, s.vertex()) for s in searches]
    for (c, u), (cost, _) in zip(vertices, _evaluate(ctx, base, vertices), strict=True):
        seen[c].append((u, cost, np.empty(0)))
    trials = []
    for c in cands:
        if seen[c]:
            u, cost, _ = min(seen[c], key=lambda s: s[1])
            trials.append(Trial(c.effect(u, ctx.scales), cost, scores[c][0]))
        else:  # screened only: its best grid point, objective unknown (not simulated on the base)
            trials.append(Trial(c.effect(scores[c][1], ctx.scales), float("inf"), scores[c][0]))
    return trials
