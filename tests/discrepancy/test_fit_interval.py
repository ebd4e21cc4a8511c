"""Calibration of a fitted parameter's interval under coloured sensor noise, on a problem whose truth is known.

The twin is replaced by a linear signal model (twin(u) = u · g over two channels) so that hundreds of recordings
cost nothing; everything else is the diagnosis's own: the noise model estimated from each recording's residual
(:func:`~discrepancy.stats.noise.sensor_noise`), its whitening, the least-squares step and the intervals of
:mod:`discrepancy.search.fit`. A 95 % interval must cover the planted value in about 95 % of recordings it was not
fitted on, under white noise and AR(1) noise at ρ 0.95; under a random-walk drift it covers less (a known
shortfall, measured); the residual resampled in short blocks alone (the interval until 2026-11-27) covers far less
under the slow noises.
"""

from __future__ import annotations

import numpy as np
import pytest

from discrepancy.search.fit import LEVEL, _bootstrap, _shift_map, noise_interval
from discrepancy.stats.noise import NoiseModel, sensor_noise

STEPS = 300
RECORDINGS = 80
DRAWS = 200  # per interval (the diagnosis draws 400)


def _noise(family: str, rng: np.random.Generator) -> np.ndarray:
    """(STEPS, 2) sensor noise of one recording."""
    white = 0.2 * rng.standard_normal((STEPS, 2))
    if family == "white":
        return white
    if family == "ar1":
        out = np.zeros((STEPS, 2))
        e = rng.standard_normal((STEPS, 2)) * np.sqrt(1.0 - 0.95**2)
        out[0] = rng.standard_normal(2)
        for t in range(1, STEPS):
            out[t] = 0.95 * out[t - 1] + e[t]
        return white + out
    return white + np.cumsum(0.1 * rng.standard_normal((STEPS, 2)), axis=0)  # drift


def _coverage(family: str, method: str) -> float:
    t = np.linspace(0.0, 1.0, STEPS)
    g = np.stack([np.sin(2 * np.pi * t) + 0.5, np.where(t > 0.4, 1.0, 0.0)], axis=1)  # a slow and a step response
    spread = np.ones(2)
    hits = 0
    for k in range(RECORDINGS):
        rng = np.random.default_rng([k, 17])
        residual = _noise(family, rng)  # the recording minus the twin at the truth (u = 0)
        noise = NoiseModel.build(("a", "b"), sensor_noise(residual, spread, g), np.zeros((0, STEPS, 2)))
        jac = -noise.whiten(g).reshape(-1, 1)  # d whiten(real − u·g) / du
        z = noise.whiten(residual)
        w = np.ones(jac.shape[0])
        u_hat = float((_shift_map(jac, w) @ z.ravel())[0])  # one least-squares step from u = 0 (exact: linear)
        z_hat = z.ravel() + jac[:, 0] * u_hat  # the residual at the estimate
        if method == "block":
            lo, hi = _bootstrap(z_hat.reshape(STEPS, 2), jac, w, seed=k, draws=DRAWS)
        else:
            lo, hi = noise_interval(noise, jac, w, seed=k, draws=DRAWS)
            b_lo, b_hi = _bootstrap(z_hat.reshape(STEPS, 2), jac, w, seed=k, draws=DRAWS)
            lo, hi = np.minimum(lo, b_lo), np.maximum(hi, b_hi)  # as fit() does
        hits += int(u_hat + lo[0] <= 0.0 <= u_hat + hi[0])
    return hits / RECORDINGS


@pytest.mark.parametrize("family", ["white", "ar1"])
def test_interval_covers_at_its_level_under_coloured_noise(family: str) -> None:
    """Measured: 0.94 (white), 0.90 (AR(1) at ρ 0.95) of 80 recordings at the 95 % level."""
    coverage = _coverage(family, "fit")
    assert LEVEL - 0.08 <= coverage <= 0.995, coverage


@pytest.mark.slow
def test_interval_under_drift_covers_less_than_its_level() -> None:
    """A known shortfall, kept in view: under a random-walk drift the 95 % interval covers 0.78 of 80 recordings.
    The noise model estimated from one record takes the walk's increments a third short, or as an AR(1) at
    ρ ≈ 1 (a random level), so its draws move the estimate less than the walk does. Still far above the short
    blocks' 0.23."""
    coverage = _coverage("drift", "fit")
    assert 0.70 <= coverage <= 0.995, coverage
    assert _coverage("drift", "block") < coverage - 0.3


@pytest.mark.slow
def test_short_blocks_alone_under_cover_slow_noise() -> None:
    """Why the noise model's draws are needed: resampling the residual in blocks of a few steps treats an AR(1)
    noise at ρ 0.95 as nearly white (measured 0.68 at the 95 % level)."""
    assert _coverage("ar1", "block") < LEVEL - 0.15
