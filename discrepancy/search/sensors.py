"""Sensor-fault candidates, fitted in closed form on one channel (no simulation needed): bias (weighted mean of
the residual), gain (weighted regression on the twin's signal) and delay (1-D search of the shift)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from discrepancy.context import Context, huber
from discrepancy.effects import Effect
from discrepancy.twin.plant import shift

DELAY_STEPS = 20  # delays searched up to this many control steps
DELAY_GRID = 81


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
    bias = float(np.sum(zr * z1) / max(np.sum(z1 * z1), 1e-300))
    out.append((Effect.make("sensor_bias", signal, {"bias": bias}), twin + bias))
    gain = float(np.sum(zr * zx) / max(np.sum(zx * zx), 1e-300))
    out.append((Effect.make("sensor_gain", signal, {"gain_error": gain}), twin * (1.0 + gain)))
    delay = _best_delay(ctx.time, real, twin, lambda y: _channel_cost(white(real - y)))
    out.append((Effect.make("sensor_delay", signal, {"delay": delay}), shift(twin, ctx.time, delay)))
    return [(e, total - own + _channel_cost(white(real - y))) for e, y in out]


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
