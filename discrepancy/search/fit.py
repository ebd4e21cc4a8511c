"""Model the named effects: fit their parameters jointly with an interval, apply them, re-simulate and compare the
residual before and after, per signal and dig phase, on held-out cycles when there are any.

Parameters are fitted in their dimensionless form Π (log Π for positive ones) by damped Gauss–Newton on the
whitened residual with finite-difference Jacobians (iteratively reweighted for the Huber objective); an iterate is
kept only when it lowers the objective. Intervals come from the linearised model at the optimum, each side the
wider of two routes: a moving-block bootstrap of the residual rows (blocks of :data:`BLOCK` steps keep the
residual's short correlation and whatever misfit the noise model does not describe) and draws of the estimated
sensor noise (:func:`noise_interval`: a slow AR(1) or a drift, which short blocks take for white noise; 0.68 against
0.90 coverage at ρ 0.95 in ``tests/discrepancy/test_fit_interval.py``). Each draw also carries what the log's own
uncertainties would have put into the parameters (:func:`_nuisance_shifts`: the null runs from other starts, with
moved command timing, sensor filters and time offset). The interval is then widened to the last Gauss–Newton step
and to :data:`RESOLUTION`. What neither route holds is a wrong model: a parameter pulled off by an effect named
beside it, or by one left out, is biased beyond its interval.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from discrepancy.context import HUBER, Context
from discrepancy.data.episode import EpisodeData
from discrepancy.effects import Effect
from discrepancy.search.candidates import Candidate
from discrepancy.stats.noise import NoiseModel
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
    nuisance = _nuisance_shifts(ctx, fitted, coords, jac, w)
    lo, hi = _bootstrap(z.reshape(ctx.real_matrix.shape), jac, w, seed, nuisance)
    n_lo, n_hi = noise_interval(ctx.noise, jac, w, seed, nuisance)
    lo, hi = np.minimum(lo, n_lo), np.maximum(hi, n_hi)
    # not converged further than the last step, nor resolved finer than the objective's roughness
    floor = np.array([RESOLUTION if c.log else RESOLUTION * max(abs(v), 1e-12) for c, v in zip(coords, u, strict=True)])
    lo, hi = np.minimum(lo, -np.maximum(np.abs(last), floor)), np.maximum(hi, np.maximum(np.abs(last), floor))
    intervals: list[dict[str, tuple[float, float]]] = [{} for _ in fitted]
    ends = [_from_u(u + d, fitted, coords, ctx) for d in (lo, hi)]
    for c in coords:
        a, b = (e[c.effect].params[c.param] for e in ends)
        intervals[c.effect][c.param] = (min(a, b), max(a, b))
    return FitResult(fitted, intervals, before, best, iterations)


def _shift_map(jac: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(coordinates, samples): the weighted least-squares map from a change of the whitened residual (raveled) to
    the parameter shift (u) that absorbs it."""
    a = jac.T @ (w[:, None] * jac)
    return -np.linalg.pinv(a + 1e-12 * np.eye(len(a))) @ (jac.T * w[None, :])


def _nuisance_shifts(ctx: Context, effects: Sequence[Effect], coords: list[Coordinate], jac: np.ndarray,
                     w: np.ndarray) -> np.ndarray | None:
    """(runs, coordinates): the parameter shift (u) that each null run's nuisance would have put into the fit, to
    first order, or None without a null that kept its runs.

    A null run replays the twin from another start the log leaves possible (a log without seed), with the
    commands moved within their timing, the sensor filters and the time offset within their estimates' spread
    (:func:`discrepancy.stats.null.calibrate`): the recording could as well have been that run plus sensor noise,
    and the fitted parameters would then have moved by what absorbs its deviation. The null also jitters the
    effects it replays (to find the corrected twin's fragile moments); that jitter is a known shift of the
    parameters themselves and is taken out, so only what the nuisance does remains."""
    null = ctx.null
    if null is None or null.deviations is None or len(null.deviations) < 2:
        return None
    shift = _shift_map(jac, w)
    out = []
    for k, dev in enumerate(null.deviations):
        z = np.nan_to_num(null.noise.whiten(dev)).ravel()  # had the recording been that run: real − twin = dev
        s = shift @ z
        if k < len(null.run_effects) and len(null.run_effects[k]) == len(effects):
            s = s - (_to_u(list(null.run_effects[k]), coords, ctx) - _to_u(list(effects), coords, ctx))
        out.append(s)
    return np.asarray(out)


def noise_interval(noise: NoiseModel | None, jac: np.ndarray, w: np.ndarray, seed: int,
                   nuisance: np.ndarray | None = None, draws: int = BOOTSTRAP) -> tuple[np.ndarray, np.ndarray]:
    """Percentile interval (:data:`LEVEL`) of the parameter shift (u) under sensor noise drawn from the estimated
    ``noise`` model (:meth:`~discrepancy.stats.noise.NoiseModel.sample`: its colour and drift, which a residual
    resampled in short blocks leaves out), each draw plus the ``nuisance``'s shift as in :func:`_bootstrap`.

    ``jac``: (samples, coordinates), the whitened residual's derivative in u; ``w``: (samples,), the robust
    weights. (0, 0) without a noise model."""
    if noise is None:
        return np.zeros(jac.shape[1]), np.zeros(jac.shape[1])
    rng = np.random.default_rng([seed, 2003])
    shift = _shift_map(jac, w)
    d = np.asarray([shift @ np.nan_to_num(noise.whiten(noise.sample(rng))).ravel() for _ in range(draws)])
    return _percentiles(_plus_nuisance(d, nuisance, rng))


def _plus_nuisance(draws: np.ndarray, nuisance: np.ndarray | None, rng: np.random.Generator) -> np.ndarray:
    """``draws`` (draws, coordinates) each plus a normal draw of the nuisance's shift (``nuisance``: (runs,
    coordinates), its second moment about zero taken as the covariance)."""
    if nuisance is None or not len(nuisance):
        return draws
    vals, vecs = np.linalg.eigh(nuisance.T @ nuisance / len(nuisance))
    root = vecs * np.sqrt(np.clip(vals, 0.0, None))[None, :]
    return draws + rng.standard_normal(draws.shape) @ root.T


def _percentiles(draws: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    q = (1.0 - LEVEL) / 2.0
    return np.quantile(draws, q, axis=0), np.quantile(draws, 1.0 - q, axis=0)


def _bootstrap(z: np.ndarray, jac: np.ndarray, w: np.ndarray, seed: int, nuisance: np.ndarray | None = None,
               draws: int = BOOTSTRAP) -> tuple[np.ndarray, np.ndarray]:
    """Percentile interval of the parameter shift (u) under moving-block resampling of the residual rows, each
    draw plus a normal draw of the nuisance's shift (``nuisance``: (runs, coordinates), its second moment about
    zero taken as the covariance)."""
    steps, _signals = z.shape
    rng = np.random.default_rng([seed, 1009])
    shift = _shift_map(jac, w)
    starts = np.arange(max(steps - BLOCK + 1, 1))
    out = []
    for _ in range(draws):
        idx = np.concatenate([np.arange(s, s + BLOCK) for s in rng.choice(starts, steps // BLOCK + 1)])[:steps]
        out.append(shift @ z[np.minimum(idx, steps - 1)].ravel())
    return _percentiles(_plus_nuisance(np.asarray(out), nuisance, rng))


#: An NRMSE is flagged ``"worse"`` when the correction raised it by more than this fraction of itself ...
WORSE_RELATIVE = 0.05
#: ... and by more than this (1 % of its normaliser): changes at the noise level are not flagged.
WORSE_ABSOLUTE = 0.01
#: A normaliser (the real signal's spread) below this fraction of the signal's scale is flagged
#: ``"normaliser near zero"``: the NRMSE then divides by almost nothing and says little.
NEAR_ZERO = 0.01
WORSE = "worse"
NORMALISER_NEAR_ZERO = "normaliser near zero"


def entry_flags(before: float, after: float, normaliser: float | None = None, scale: float | None = None
                ) -> list[str]:
    """Flags of one before/after NRMSE pair: :data:`WORSE` when the correction raised it (beyond
    :data:`WORSE_RELATIVE` and :data:`WORSE_ABSOLUTE`, or to a non-finite value), :data:`NORMALISER_NEAR_ZERO`
    when ``normaliser`` is below :data:`NEAR_ZERO` × ``scale`` (not judged when either is unknown)."""
    out = []
    if (not np.isfinite(after) and np.isfinite(before)) or (
            after > before * (1.0 + WORSE_RELATIVE) and after - before > WORSE_ABSOLUTE):
        out.append(WORSE)
    if normaliser is not None and scale is not None and (normaliser <= 1e-12 or normaliser < NEAR_ZERO * scale):
        out.append(NORMALISER_NEAR_ZERO)
    return out


@dataclass
class Comparison:
    """NRMSE (RMS residual / spread of the real signal) per signal, overall and per phase, before and after the
    correction, with what each NRMSE divides by, so that entries not to be trusted are flagged (:meth:`flags`).

    ``normaliser``: signal → the spread its overall NRMSE divides by (SI); ``phase_normaliser``: signal → phase →
    the spread within that phase; ``scale``: signal → its magnitude (the larger RMS of the real signal and of the
    nominal twin, SI), against which a normaliser counts as near zero.
    """

    before: dict[str, float] = field(default_factory=dict)
    after: dict[str, float] = field(default_factory=dict)
    by_phase: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)
    held_out: bool = False
    normaliser: dict[str, float] = field(default_factory=dict)
    phase_normaliser: dict[str, dict[str, float]] = field(default_factory=dict)
    scale: dict[str, float] = field(default_factory=dict)

    def flags(self, signal: str, phase: str | None = None) -> list[str]:
        """Flags of one entry, overall (``phase`` None) or in one phase: see :func:`entry_flags`."""
        if phase is None:
            before, after, norm = self.before[signal], self.after[signal], self.normaliser.get(signal)
        else:
            before, after = self.by_phase[signal][phase]
            norm = self.phase_normaliser.get(signal, {}).get(phase)
        return entry_flags(before, after, norm, self.scale.get(signal))

    @property
    def flagged(self) -> dict[str, list[str]]:
        """Signal → flags of its overall entry, flagged signals only."""
        return {s: f for s in self.before if s in self.after and (f := self.flags(s))}

    @property
    def phase_flagged(self) -> dict[str, dict[str, list[str]]]:
        """Signal → phase → flags, flagged phases only."""
        out: dict[str, dict[str, list[str]]] = {}
        for s, phases in self.by_phase.items():
            found = {p: f for p in phases if (f := self.flags(s, p))}
            if found:
                out[s] = found
        return out

    @property
    def worse(self) -> list[str]:
        """Signals whose overall NRMSE the correction made worse."""
        return [s for s, f in self.flagged.items() if WORSE in f]

    def residual(self, corrected: bool) -> float:
        """Σ over signals of RMS residual / scale (the NRMSE where normaliser or scale is unknown): an overall
        measure that a near-zero normaliser does not inflate. ``corrected``: after the correction, else before."""
        values = self.after if corrected else self.before
        total = 0.0
        for s, v in values.items():
            norm, scale = self.normaliser.get(s), self.scale.get(s)
            total += v * norm / scale if norm is not None and scale else v
        return float(total)

    @property
    def worse_overall(self) -> bool:
        """The correction raised the overall residual (:meth:`residual`) by more than :data:`WORSE_RELATIVE`."""
        before, after = self.residual(False), self.residual(True)
        return not np.isfinite(after) or after > before * (1.0 + WORSE_RELATIVE)


def _spread(real: np.ndarray) -> float:
    """What an NRMSE divides by: the real signal's standard deviation (its mean's size if it is constant)."""
    return float(np.std(real)) or max(abs(float(np.mean(real))), 1e-12)


def _nrmse(real: np.ndarray, twin: np.ndarray, spread: float) -> float:
    r = real - twin
    r = np.where(np.isfinite(r), r, spread * 10.0)
    return float(np.sqrt(np.mean(r**2)) / spread)


def _rms(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if x.size else 0.0


def compare(episodes: Sequence[EpisodeData], replays: Sequence[CachedReplays], names: Sequence[str],
            effects: Sequence[Effect], held_out: bool) -> Comparison:
    """Residual of the nominal and of the corrected twin on ``episodes`` (pooled), with the normalisers and
    scales that :meth:`Comparison.flags` judges."""
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
        spread = _spread(r)
        out.normaliser[s], out.scale[s] = spread, max(_rms(r), _rms(n))
        out.before[s], out.after[s] = _nrmse(r, n, spread), _nrmse(r, c, spread)
        out.by_phase[s], out.phase_normaliser[s] = {}, {}
        for p in dict.fromkeys(labels):
            m = labels == p
            if np.sum(m) > 1:
                sp = _spread(r[m])
                out.phase_normaliser[s][str(p)] = sp
                out.by_phase[s][str(p)] = (_nrmse(r[m], n[m], sp), _nrmse(r[m], c[m], sp))
    return out
