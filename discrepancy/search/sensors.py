"""Sensor-fault candidates, fitted in closed form on one channel (no simulation needed): bias (weighted mean of
the residual), gain (weighted regression on the twin's signal) and delay (1-D search of the shift).

A drifting level reads as an offset: a bias is not tried where a random walk from zero explains the channel's level
as well as a constant, nor, on a channel whose noise model drifts (:mod:`discrepancy.stats.noise`), unless a
constant offset gains more than :data:`OFFSET_EVIDENCE` times what it gains on the null runs (drift alone,
``NoiseModel.bias_null``); likewise a gain on a drifting channel (``NoiseModel.gain_null``); the reason is
recorded in ``NoiseModel.withheld``."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from discrepancy.context import Context, huber
from discrepancy.effects import Effect
from discrepancy.stats.noise import NoiseModel, linear_evidence, offset_or_drift
from discrepancy.twin.plant import shift

DELAY_STEPS = 20  # delays searched up to this many control steps
DELAY_GRID = 81
#: Objective gain a constant offset must bring on a drifting channel, in units of its mean gain on the null runs
#: (at least 1): the bar a round's winner must clear anyway (``identify.MIN_GAIN``), here against the drift.
OFFSET_EVIDENCE = 25.0


def _channel_cost(z: np.ndarray) -> float:
    return float(np.sum(huber(z)))


def sensor_trials(ctx: Context, base: np.ndarray, signal: str) -> list[tuple[Effect, float]]:
    """Best bias, gain and delay on ``signal`` over the base twin ``base`` (steps, signals): (effect, objective).

    Bias and gain are generalised least squares: the residual and the regressor pass through the channel's
    whitening filter (linear), so coloured noise weighs as it should."""
    j = ctx.names.index(signal)
    noise = ctx.noise
    assert noise is not None
    real, twin = ctx.real_matrix[:, j], base[:, j]
    ok = np.isfinite(twin)
    r = np.where(ok, real - twin, 0.0)
    x = np.where(ok, twin, 0.0)

    def white(v: np.ndarray) -> np.ndarray:
        return np.where(ok, noise.whiten_channel(v, j), 0.0)

    total = ctx.cost(base)
    own = _channel_cost(ctx.z(base)[:, j])
    out = []
    zr, z1, zx = white(r), white(np.ones_like(r)), white(x)
    if _offset_credible(noise, j, float(linear_evidence(zr, z1)), r):
        bias = float(np.sum(zr * z1) / max(np.sum(z1 * z1), 1e-300))
        out.append((Effect.make("sensor_bias", signal, {"bias": bias}), twin + bias))
    if _gain_credible(noise, j, float(linear_evidence(zr, zx))):
        gain = float(np.sum(zr * zx) / max(np.sum(zx * zx), 1e-300))
        out.append((Effect.make("sensor_gain", signal, {"gain_error": gain}), twin * (1.0 + gain)))
    delay = _best_delay(ctx.time, real, twin, lambda y: _channel_cost(white(real - y)))
    out.append((Effect.make("sensor_delay", signal, {"delay": delay}), shift(twin, ctx.time, delay)))
    return [(e, total - own + _channel_cost(white(real - y))) for e, y in out]


def _offset_credible(noise: NoiseModel, j: int, evidence: float, residual: np.ndarray) -> bool:
    """May a constant offset on channel ``j`` be a sensor bias, given its ``evidence`` (objective gain, whitened
    units) and the channel's ``residual`` (steps,)? Not when a random walk from zero explains the residual's level
    as well as a constant does (:func:`~discrepancy.stats.noise.offset_or_drift`: the level wanders), nor, on a
    channel whose noise model drifts, below :data:`OFFSET_EVIDENCE` times what drift alone gains in the null runs
    (:func:`_drift_reason`). The reason is recorded in ``noise.withheld``."""
    short = dataclasses.replace(noise.channels[j], drift=0.0)
    null = None if noise.bias_null is None else noise.bias_null[j]
    margin = offset_or_drift(residual, short)
    if margin < 0.0:
        reason: str | None = (f"a random walk from zero explains its level better than a constant offset (by "
                              f"{-margin:.1f} log-likelihood): drift, not a bias")
    else:
        reason = _drift_reason(noise, j, evidence, null, "a constant offset")
    if reason is None:
        return True
    noise.withheld[noise.names[j]] = f"sensor_bias not named: {reason}"
    return False


def _gain_credible(noise: NoiseModel, j: int, evidence: float) -> bool:
    """May a multiple of the twin's signal on channel ``j`` be a sensor gain, given its ``evidence`` (objective
    gain, whitened units)? On a channel whose noise model drifts, not below :data:`OFFSET_EVIDENCE` times what a
    gain gains in the null runs (``NoiseModel.gain_null``: a walk that wandered along a slowly rising signal, a
    payload's mass as the bucket fills, reads as a gain as readily as a level reads as a bias; :func:`_drift_reason`).
    The reason is recorded in ``noise.withheld``."""
    if noise.gain_null is None:
        return True
    reason = _drift_reason(noise, j, evidence, noise.gain_null[j], "a gain")
    if reason is None:
        return True
    name = noise.names[j]
    noise.withheld[name] = "; ".join(filter(None, [noise.withheld.get(name), f"sensor_gain not named: {reason}"]))
    return False


def _drift_reason(noise: NoiseModel, j: int, evidence: float, null: float | None, what: str) -> str | None:
    """Why a sensor fault (``what``: "a constant offset", "a gain") with ``evidence`` on channel ``j`` is not
    named: its noise model drifts and the evidence is below :data:`OFFSET_EVIDENCE` times ``null``, what the fault
    gains on the null runs (at least 1; 1 where there is none); None when it may be named."""
    drift = noise.channels[j].drift
    floor = 1.0 if null is None else max(1.0, float(null))
    if drift == 0.0 or evidence >= OFFSET_EVIDENCE * floor:
        return None
    return (f"its noise drifts (random walk {drift:.3g} per step); {what} gains {evidence:.1f}, below "
            f"{OFFSET_EVIDENCE:g} x {floor:.2f} (its mean gain on the null runs)")


def _best_delay(time: np.ndarray, real: np.ndarray, twin: np.ndarray, cost: Callable[[np.ndarray], float]) -> float:
    dt = float(np.median(np.diff(time)))
    grid = np.linspace(0.0, DELAY_STEPS * dt, DELAY_GRID)
    costs = np.array([cost(shift(twin, time, d)) for d in grid])
    k = int(np.argmin(costs))
    if 0 < k < len(grid) - 1:  # parabola through the best three
        c0, c1, c2 = costs[k - 1:k + 2]
        denom = c0 - 2 * c1 + c2
        if denom > 0:
            return float(grid[k] + 0.5 * (c0 - c2) / denom * (grid[1] - grid[0]))
    return float(grid[k])
