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
    channel whose noise model drifts, below :data:`OFFSET_EVIDENCE` times what drift alone gains in the null runs.
    The reason is recorded in ``noise.withheld``."""
    channel = noise.channels[j]
    short = dataclasses.replace(channel, drift=0.0)
    null = 1.0 if noise.bias_null is None else max(1.0, float(noise.bias_null[j]))
    margin = offset_or_drift(residual, short)
    if margin < 0.0:
        reason = (f"a random walk from zero explains its level better than a constant offset (by {-margin:.1f} "
                  "log-likelihood): drift, not a bias")
    elif channel.drift > 0.0 and evidence < OFFSET_EVIDENCE * null:
        reason = (f"its noise drifts (random walk {channel.drift:.3g} per step); a constant offset gains "
                  f"{evidence:.1f}, below {OFFSET_EVIDENCE:g} x {null:.2f} (its mean gain on the null runs)")
    else:
        return True
    noise.withheld[noise.names[j]] = f"sensor_bias not named: {reason}"
    return False


def _gain_credible(noise: NoiseModel, j: int, evidence: float) -> bool:
    """May a multiple of the twin's signal on channel ``j`` be a sensor gain, given its ``evidence`` (objective
    gain, whitened units)? On a channel whose noise model drifts, not below :data:`OFFSET_EVIDENCE` times what a
    gain gains in the null runs (``NoiseModel.gain_null``: a walk that wandered along a slowly rising signal, a
    payload's mass as the bucket fills, reads as a gain as readily as a level reads as a bias). The reason is
    recorded in ``noise.withheld``."""
    channel = noise.channels[j]
    if channel.drift == 0.0 or noise.gain_null is None:
        return True
    null = max(1.0, float(noise.gain_null[j]))
    if evidence >= OFFSET_EVIDENCE * null:
        return True
    reason = (f"its noise drifts (random walk {channel.drift:.3g} per step); a gain gains {evidence:.1f}, below "
              f"{OFFSET_EVIDENCE:g} x {null:.2f} (its mean gain on the null runs)")
    name = noise.names[j]
    noise.withheld[name] = "; ".join(filter(None, [noise.withheld.get(name), f"sensor_gain not named: {reason}"]))
    return False


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
