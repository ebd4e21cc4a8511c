"""Model the named effects: fit their parameters jointly with an interval, apply them, re-simulate and compare the
residual before and after, per signal and dig phase, on held-out cycles when there are any.

Parameters are fitted in their dimensionless form Π (log Π for positive ones) by damped Gauss–Newton on the
whitened residual with finite-difference Jacobians (iteratively reweighted for the Huber objective); an iterate is
kept only when it lowers the objective. Intervals come from a moving-block residual bootstrap of the linearised
model at the optimum (blocks of :data:`BLOCK` steps keep the residual's time correlation), widened to the last
Gauss–Newton step and to :data:`RESOLUTION`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from discrepancy.context import HUBER, Context
from discrepancy.data.episode import EpisodeData
from discrepancy.effects import Effect
from discrepancy.search.candidates import Candidate
from discrepancy.twin.runner import CachedReplays

GN_ITERATIONS = 3
BOOTSTRAP = 400
BLOCK = 5
LEVEL = 0.95
FD_STEP = {"actuator_delay": 0.002}  # log-step of sharp parameters (default FD_LOG)
FD_LOG = 0.005  # small: the objective has jumps (fragile moments) a few per cent away from the optimum
FD_LINEAR = 0.005
SCAN = (-0.3, -0.15, -0.07, -0.03, -0.01, 0.01, 0.03, 0.07, 0.15, 0.3)  # relative (log) offsets of the scan
FINE_SCAN = (-0.004, 0.004)
#: Dense scans of the accepted effects before another is added: the objective is a comb (stick-slip, valve and
#: contact events) with narrow dips a few per cent apart, and a near miss leaves a residual that a sibling effect
#: would otherwise "explain".
DENSE_SCAN = (-0.05, -0.035, -0.025, -0.018, -0.012, -0.008, -0.005, -0.0025, 0.0025, 0.005, 0.008, 0.012, 0.018,
              0.025, 0.035, 0.05)
DENSE_FINE = (-0.0015, -0.0008, 0.0008, 0.0015)
#: Relative resolution of a fitted parameter: the objective is rough on this scale (twin moments that jump), so an
#: interval is never narrower than ± this (in log Π, or relative for signed parameters).
RESOLUTION = 0.02
TRUST = 0.7  # largest Gauss–Newton step (log Π, or relative for signed parameters)


@dataclass(frozen=True)
class Coordinate:
    """One fitted parameter: effect index, name, and whether it is searched in log Π."""

    effect: int
    param: str
    log: bool


@dataclass
class FitResult:
    """Fitted effects (SI), their intervals (SI, by effect then parameter) and the objective before and after."""

    effects: list[Effect]
    intervals: list[dict[str, tuple[float, float]]]
    cost_before: float
    cost_after: float
    iterations: int = 0


def _coordinates(effects: Sequence[Effect]) -> list[Coordinate]:
    out = []
    for i, e in enumerate(effects):
        for p in e.spec.params:
            out.append(Coordinate(i, p.name, p.log and e.params[p.name] > 0))
    return out


def _to_u(effects: Sequence[Effect], coords: list[Coordinate], ctx: Context) -> np.ndarray:
    pis = [e.to_pi(ctx.scales) for e in effects]
    return np.array([np.log(pis[c.effect][c.param]) if c.log else pis[c.effect][c.param] for c in coords])


def _from_u(u: np.ndarray, effects: Sequence[Effect], coords: list[Coordinate], ctx: Context) -> list[Effect]:
    pis = [e.to_pi(ctx.scales) for e in effects]
    for c, v in zip(coords, u, strict=True):
        pis[c.effect][c.param] = float(np.exp(v)) if c.log else float(v)
    return [Effect.from_pi(e.name, e.target, p, ctx.scales) for e, p in zip(effects, pis, strict=True)]


def _bounds(effects: Sequence[Effect], coords: list[Coordinate], ctx: Context) -> np.ndarray:
    """(coordinates, 2) admissible range in u (the catalogue's bounds; a soil term may not go below zero)."""
    rows = []
    for c in coords:
        e = effects[c.effect]
        k = [p.name for p in e.spec.params].index(c.param)
        lo, hi = Candidate(e.name, e.target).bounds(ctx.scales)[k] if e.spec.params[k].log == c.log else (
            e.spec.params[k].bounds)
        rows.append((lo, hi))
    return np.array(rows, dtype=float)


def _trust(delta: np.ndarray, u: np.ndarray, coords: list[Coordinate]) -> np.ndarray:
    """Limit a step to ±TRUST in log Π, or ±TRUST × max(|u|, 0.01) for signed parameters."""
    cap = np.array([TRUST if c.log else TRUST * max(abs(v), 0.01) for c, v in zip(coords, u, strict=True)])
    return np.clip(np.nan_to_num(delta), -cap, cap)


def _step(c: Coordinate, u: float, effects: Sequence[Effect]) -> float:
    name = effects[c.effect].name
    if c.log:
        return FD_STEP.get(name, FD_LOG)
    return max(FD_LINEAR * abs(u), 1e-4)


def _jacobian(ctx: Context, effects: list[Effect], coords: list[Coordinate], u: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    steps = np.array([_step(c, v, effects) for c, v in zip(coords, u, strict=True)])
    points = [u] + [u + h * e for h, e in zip(steps, np.eye(len(u)), strict=True)]
    mats = ctx.simulate_many([_from_u(p, effects, coords, ctx) for p in points])
    z = [ctx.z(m).ravel() for m in mats]
    jac = np.stack([(zi - z[0]) / h for zi, h in zip(z[1:], steps, strict=True)], axis=1)
    return z[0], jac, np.minimum(1.0, HUBER / np.maximum(np.abs(z[0]), 1e-12))


def _solve(jac: np.ndarray, w: np.ndarray, z: np.ndarray) -> np.ndarray:
    a = jac.T @ (w[:, None] * jac)
    lam = 1e-6 * np.trace(a) / max(len(a), 1) + 1e-12
    return np.linalg.solve(a + lam * np.eye(len(a)), -jac.T @ (w * z))


def scan(ctx: Context, effects: Sequence[Effect], first: int,
         passes: Sequence[Sequence[float]] = (SCAN, FINE_SCAN)) -> tuple[list[Effect], float]:
    """Coordinate scans of every parameter (those of ``effects[first]`` first) at a few relative offsets, then
    finer ones around the best (``passes``: log offsets, or relative for signed parameters): the objective has
    jumps (fragile moments) that trap a purely local method a few per cent off, and effects found earlier may
    have absorbed part of a later one. Stops (keeping the best so far) when the context's budget is spent."""
    effects = list(effects)
    coords = _coordinates(effects)
    u = _to_u(effects, coords, ctx)
    best = ctx.cost(ctx.simulate(effects))
    bounds = _bounds(effects, coords, ctx)
    order = sorted(range(len(coords)), key=lambda i: coords[i].effect != first)
    for i in order:
        c = coords[i]
        for offsets in passes:
            if ctx.budget.exhausted():
                return _from_u(u, effects, coords, ctx), best
            scale = 1.0 if c.log else max(abs(u[i]), 1e-3)
            points = [np.clip(u + o * scale * np.eye(len(u))[i], bounds[:, 0], bounds[:, 1]) for o in offsets]
            costs = [ctx.cost(m) for m in ctx.simulate_many([_from_u(p, effects, coords, ctx) for p in points])]
            k = int(np.argmin(costs))
            if costs[k] < best:
                u, best = points[k], costs[k]
    return _from_u(u, effects, coords, ctx), best


def polish(ctx: Context, effects: Sequence[Effect], iterations: int = GN_ITERATIONS, budgeted: bool = True
           ) -> tuple[list[Effect], float, np.ndarray, int]:
    """Damped Gauss–Newton on all parameters of ``effects`` jointly; an iterate is kept only when it lowers the
    objective; with ``budgeted``, no iteration starts once the context's budget is spent. Returns the effects,
    their objective, the last step (u) and the number of accepted steps."""
    effects = list(effects)
    coords = _coordinates(effects)
    u = _to_u(effects, coords, ctx)
    best = ctx.cost(ctx.simulate(effects))
    accepted = 0
    last = np.zeros_like(u)
    bounds = _bounds(effects, coords, ctx)
    for _ in range(iterations):
        if budgeted and ctx.budget.exhausted():
            break
        z, jac, w = _jacobian(ctx, effects, coords, u)
        delta = _trust(_solve(jac, w, z), u, coords)
        trials = [np.clip(u + f * delta, bounds[:, 0], bounds[:, 1]) for f in (1.0, 0.5, 0.25)]
        costs = [ctx.cost(m) for m in ctx.simulate_many([_from_u(t, effects, coords, ctx) for t in trials])]
        k = int(np.argmin(costs))
        last = delta
        if costs[k] >= best:
            break
        u, best, accepted = trials[k], costs[k], accepted + 1
    return _from_u(u, effects, coords, ctx), best, last, accepted


def fit(ctx: Context, effects: Sequence[Effect], seed: int = 0, iterations: int = GN_ITERATIONS) -> FitResult:
    """Refine ``effects`` jointly (``iterations`` Gauss–Newton steps) and bootstrap their intervals."""
    before = ctx.cost(ctx.simulate([]))
    if not effects:
        return FitResult([], [], before, before)
    fitted, best, last, iterations = polish(ctx, effects, iterations, budgeted=False)
    coords = _coordinates(fitted)
    u = _to_u(fitted, coords, ctx)
    z, jac, w = _jacobian(ctx, fitted, coords, u)
    lo, hi = _bootstrap(z.reshape(ctx.real_matrix.shape), jac, w, seed)
    # not converged further than the last step, nor resolved finer than the objective's roughness
    floor = np.array([RESOLUTION if c.log else RESOLUTION * max(abs(v), 1e-12) for c, v in zip(coords, u, strict=True)])
    lo, hi = np.minimum(lo, -np.maximum(np.abs(last), floor)), np.maximum(hi, np.maximum(np.abs(last), floor))
    intervals: list[dict[str, tuple[float, float]]] = [{} for _ in fitted]
    ends = [_from_u(u + d, fitted, coords, ctx) for d in (lo, hi)]
    for c in coords:
        a, b = (e[c.effect].params[c.param] for e in ends)
        intervals[c.effect][c.param] = (min(a, b), max(a, b))
    return FitResult(fitted, intervals, before, best, iterations)


def _bootstrap(z: np.ndarray, jac: np.ndarray, w: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Percentile interval of the parameter shift (u) under moving-block resampling of the residual rows."""
    steps, _signals = z.shape
    rng = np.random.default_rng([seed, 1009])
    a = jac.T @ (w[:, None] * jac)
    a_inv = np.linalg.pinv(a + 1e-12 * np.eye(len(a)))
    starts = np.arange(max(steps - BLOCK + 1, 1))
    draws = []
    for _ in range(BOOTSTRAP):
        idx = np.concatenate([np.arange(s, s + BLOCK) for s in rng.choice(starts, steps // BLOCK + 1)])[:steps]
        e = z[np.minimum(idx, steps - 1)].ravel()
        draws.append(-a_inv @ (jac.T @ (w * e)))
    d = np.asarray(draws)
    q = (1.0 - LEVEL) / 2.0
    return np.quantile(d, q, axis=0), np.quantile(d, 1.0 - q, axis=0)


@dataclass
class Comparison:
    """NRMSE (RMS residual / spread of the real signal) per signal, overall and per phase, before and after."""

    before: dict[str, float] = field(default_factory=dict)
    after: dict[str, float] = field(default_factory=dict)
    by_phase: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)
    held_out: bool = False


def _nrmse(real: np.ndarray, twin: np.ndarray) -> float:
    spread = float(np.std(real)) or max(abs(float(np.mean(real))), 1e-12)
    r = real - twin
    r = np.where(np.isfinite(r), r, spread * 10.0)
    return float(np.sqrt(np.mean(r**2)) / spread)


def compare(episodes: Sequence[EpisodeData], replays: Sequence[CachedReplays], names: Sequence[str],
            effects: Sequence[Effect], held_out: bool) -> Comparison:
    """Residual of the nominal and of the corrected twin on ``episodes`` (pooled)."""
    out = Comparison(held_out=held_out)
    real, nominal, corrected, phases = {}, {}, {}, []
    for ep, rep in zip(episodes, replays, strict=True):
        a, b = rep.get([]), rep.get(list(effects))
        for s in names:
            real.setdefault(s, []).append(ep.signals[s])
            nominal.setdefault(s, []).append(a.signals[s])
            corrected.setdefault(s, []).append(b.signals[s])
        phases.append(np.asarray(ep.phases, dtype=str))
    labels = np.concatenate(phases)
    for s in names:
        r, n, c = (np.concatenate(d[s]) for d in (real, nominal, corrected))
        out.before[s], out.after[s] = _nrmse(r, n), _nrmse(r, c)
        out.by_phase[s] = {str(p): (_nrmse(r[labels == p], n[labels == p]), _nrmse(r[labels == p], c[labels == p]))
                           for p in dict.fromkeys(labels) if np.sum(labels == p) > 1}
    return out
