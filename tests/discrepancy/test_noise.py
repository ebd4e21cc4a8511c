"""The sensor-noise model: a known AR(1) recovered, white noise called white even beside a slow discrepancy, the
whitening filter making coloured noise white and leaving white noise alone, drift (a random walk) found on long
time scales and kept from passing for a sensor bias, and coloured-noise nulls end to end."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import signal

from discrepancy import DiagnoseOptions, TwinSpec, diagnose
from discrepancy.bench.synth import record
from discrepancy.search.sensors import OFFSET_EVIDENCE
from discrepancy.stats.noise import (
    ChannelNoise,
    NoiseModel,
    Whitener,
    estimate_channel,
    offset_or_drift,
    sensor_noise,
)

STEPS = 300  # a long dig cycle at the control step


def _ar1(rng: np.random.Generator, rho: float, sd: float, n: int = STEPS) -> np.ndarray:
    return signal.lfilter([1.0], [1.0, -rho], rng.standard_normal(n)) * sd * np.sqrt(1.0 - rho**2)


@pytest.mark.parametrize("rho", [0.6, 0.9])
def test_a_known_ar1_is_recovered(rho: float) -> None:
    fits = [estimate_channel(_ar1(np.random.default_rng(k), rho, 1.0) + 0.2 * np.random.default_rng(100 + k)
                             .standard_normal(STEPS), 1e-9) for k in range(20)]
    rhos = np.array([f.rho for f in fits])
    assert np.mean(rhos > 0) >= 0.9, rhos  # called coloured
    assert abs(np.median(rhos) - rho) <= 0.1, rhos
    assert abs(np.median([f.coloured for f in fits]) - 1.0) <= 0.3
    assert abs(np.median([f.white for f in fits]) - 0.2) <= 0.15


def test_white_noise_is_white_even_beside_a_slow_discrepancy() -> None:
    """The slow discrepancy does not colour the channel; an undecided channel is widened to the largest SD the
    spectrum does not rule out (``PLAUSIBLE``), here by about 13 % (1.06 before that rule): the price of not
    under-stating short coloured records, bounded at 20 %."""
    t = np.linspace(0.0, 1.0, STEPS)
    slow = 5.0 * t**2 + 2.0 * ((t > 0.5) & (t < 0.6))  # a drift-like ramp and a step, 5 noise SDs
    fits = [estimate_channel(np.random.default_rng(k).standard_normal(STEPS) + slow, 1e-9) for k in range(20)]
    assert sum(f.coloured > 0 for f in fits) <= 2, [f.rho for f in fits]
    assert 0.95 <= np.median([f.white for f in fits]) <= 1.2


@pytest.mark.parametrize("rho, steps, low", [(0.6, 60, 0.87), (0.74, 50, 0.78)])
def test_short_coloured_noise_is_not_understated(rho: float, steps: int, low: float) -> None:
    """On a short record the differences often cannot tell AR(1) noise from white; a channel left undecided must not
    be given much less noise than it has (its marginal SD is 1 here): of 200 records, those not given a drift (which
    models the slow part instead) have an estimated marginal SD of at least ``low`` in 9 of 10. Calling such a
    channel white with the variance of its differences gave 0.83 and 0.76 (this rule 0.91 and 0.80)."""
    fits = [estimate_channel(_ar1(np.random.default_rng(500 + k), rho, 1.0, steps), 1e-9) for k in range(200)]
    sd = [f.sd for f in fits if f.drift == 0.0]
    assert np.percentile(sd, 10) >= low, sorted(round(x, 3) for x in sd)[:20]


def test_whitening_makes_coloured_noise_white_and_leaves_white_noise_alone() -> None:
    rng = np.random.default_rng(3)
    model = ChannelNoise(white=0.3, rho=0.9, coloured=1.0)
    x = model.sample(rng, 4000)
    lag1_raw = np.corrcoef(x[:-1], x[1:])[0, 1]
    w = Whitener([model], len(x))
    z = w.apply(x[:, None])[:, 0] / np.sqrt(w.variance[:, 0])
    assert lag1_raw > 0.7
    assert abs(np.corrcoef(z[:-1], z[1:])[0, 1]) < 0.05  # white after
    assert np.std(z) == pytest.approx(1.0, abs=0.05)  # unit variance: the Kalman innovation variance is right
    white = Whitener([ChannelNoise(white=2.0)], 50)
    y = rng.standard_normal((50, 1))
    np.testing.assert_allclose(white.apply(y), y)


def test_noise_model_whitens_column_by_column_like_the_whole() -> None:
    rng = np.random.default_rng(5)
    channels = [ChannelNoise(0.5, 0.8, 1.0), ChannelNoise(1.0)]
    model = NoiseModel.build(("a", "b"), channels, np.zeros((0, 120, 2)))
    r = np.stack([c.sample(rng, 120) for c in channels], axis=1)
    whole = model.whiten(r)
    for j in range(2):
        np.testing.assert_allclose(model.whiten_channel(r[:, j], j), whole[:, j])


def _coloured(clean, rho: float, frac: float, seed: int):
    """``clean`` with AR(1) noise of ``frac`` × each channel's range plus a fifth of that white (the benchmark's
    generator is separate; this is the simplest coloured case)."""
    rng = np.random.default_rng(seed)
    out = {}
    for k, v in clean.signals.items():
        sd = frac * max(float(np.ptp(v)), 1e-9)
        out[k] = v + _ar1(rng, rho, sd, len(v)) + 0.2 * sd * rng.standard_normal(len(v))
    return dataclasses.replace(clean, signals=out)


@pytest.mark.slow
@pytest.mark.parametrize("rho", [0.6, 0.9])
def test_a_perfect_twin_under_coloured_noise_is_not_called_wrong(twin: TwinSpec, rho: float) -> None:
    """A perfect ER12 twin under AR(1) noise (1 % of range) names nothing. At ρ 0.9 on this 99-step cycle the colour
    evidence of ``lift_speed`` is 9.0, under ``COLOUR_EVIDENCE``: called white with the variance of its differences
    it had a gain named; as an undecided channel, widened to what the spectrum does not rule out, it is quiet."""
    clean = record(twin, [], 0.0, twin.seed).clean
    d = diagnose(_coloured(clean, rho, 0.01, 5), twin, options=DiagnoseOptions())
    assert not d.effects, [(e.effect, e.target) for e in d.effects]


# --- drift ---------------------------------------------------------------------------------------------------------
# Drift here is made by this file's own generator (a random walk of a given increment SD per step beside white noise
# of SD 1), with seeds and magnitudes the noise model was not tuned on (tuning used seeds 1000-1099 and 2000-2029,
# one magnitude, 0.2 per step).

DRIFTS = (0.05, 0.1, 0.2, 0.4)  # random-walk increment SD per step, relative to the white SD
HELD_OUT = range(7000, 7008)
#: Weak walks whose level may still be named as a bias: one that moved early and then sat looks like a bias in a
#: single record (seed 7003 at 0.05 and 0.1; 2 of 12 seeds in a wider trial). Known limit, kept visible here.
WEAK = {0.05: 1, 0.1: 1}


def _drifting(seed: int, drift: float, n: int = STEPS) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.standard_normal(n) + np.cumsum(drift * rng.standard_normal(n))


def _model(residual: np.ndarray) -> NoiseModel:
    """The noise model of one channel as the null builds it, with the null's mean offset evidence (its runs: noise
    drawn from the model, the model re-estimated, a constant offset fitted)."""
    noise = NoiseModel.build(("x",), sensor_noise(residual[:, None], np.array([1.0])), np.zeros((0, len(residual), 1)))
    rng = np.random.default_rng(99)
    offsets = []
    for _ in range(4):  # fewer null runs than the pipeline's 8: the test stays fast
        sensed = noise.sample(rng)
        again = NoiseModel.build(("x",), sensor_noise(sensed, np.array([1.0])), np.zeros((0, len(residual), 1)))
        offsets.append(again.bias_evidence(sensed))
    noise.bias_null = np.mean(offsets, axis=0)
    return noise


def test_white_noise_has_no_drift() -> None:
    fits = [estimate_channel(np.random.default_rng(k).standard_normal(n), 1e-9)
            for k in HELD_OUT for n in (100, 300)]
    assert sum(f.drift > 0 for f in fits) <= 1, [f.drift for f in fits]


@pytest.mark.parametrize("drift", [0.2, 0.4])
def test_a_random_walk_is_found_and_its_rate_recovered(drift: float) -> None:
    fits = [estimate_channel(_drifting(k, drift), 1e-9) for k in HELD_OUT]
    found = [f for f in fits if f.drift > 0 or f.rho > 0.99]  # found as drift, or (strong) as ρ → 1 colour
    assert len(found) >= 0.75 * len(fits), [(f.drift, f.rho) for f in fits]
    rates = [f.drift for f in fits if f.drift > 0]
    assert abs(np.log(np.median(rates) / drift)) < np.log(2.0), rates


def _offset_named(r: np.ndarray) -> bool:
    """Would the sensor-fault search try a bias on this one-channel residual (the rule of ``search/sensors.py``)?"""
    model = _model(r)
    evidence = float(model.bias_evidence(r[:, None])[0])
    if offset_or_drift(r, dataclasses.replace(model.channels[0], drift=0.0)) < 0.0:
        return False
    bar = OFFSET_EVIDENCE * max(1.0, float(model.bias_null[0])) if model.drifting else OFFSET_EVIDENCE
    return evidence >= bar


@pytest.mark.parametrize("drift", DRIFTS)
def test_drift_alone_does_not_pass_for_a_sensor_bias(drift: float) -> None:
    """(a) Drifting nulls of several magnitudes and held-out seeds: no offset that would be named as a bias."""
    named = [k for k in HELD_OUT if _offset_named(_drifting(k, drift))]
    assert len(named) <= WEAK.get(drift, 0), named


def test_white_nulls_stay_clean_and_a_bias_under_white_noise_is_seen() -> None:
    """(b) White nulls: no drift, no offset named; (c) a bias of 0.4 noise SD over 300 steps (evidence about 50):
    named, on a channel called white."""
    for k in HELD_OUT:
        r = np.random.default_rng(k).standard_normal(STEPS)
        assert not _model(r).drifting and not _offset_named(r)
        assert _offset_named(r + 0.4), k
