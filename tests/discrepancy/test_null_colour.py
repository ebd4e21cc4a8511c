"""Sensor noise beside the twin's slow signals (issue 14): a random walk's rate is estimated with the twin's own
signal and rate as free regressors (a restricted likelihood), so a walk that partly resembles a ramp of the twin
keeps its rate and a gain on that ramp is not taken for a walk; end to end (slow), benchmark nulls under AR(1) and
drift noise that the regression-first estimate left too narrow stay clean, and a sensor gain under white noise is
still named."""

from __future__ import annotations

import numpy as np
import pytest

from discrepancy.bench.cases import make_case
from discrepancy.bench.run import run_case
from discrepancy.bench.sensor_noise import channel_range
from discrepancy.bench.synth import field_recording, simulate
from discrepancy.pipeline import DiagnoseOptions, diagnose
from discrepancy.search.sensors import OFFSET_EVIDENCE, _gain_credible
from discrepancy.stats.locate import locate, windows
from discrepancy.stats.noise import (
    ChannelNoise,
    _unexplained_by,
    estimate_drift,
    level_loglik,
    regression_loglik,
    sensor_noise,
)
from discrepancy.stats.null import null_from_arrays


def _ramp(steps: int) -> np.ndarray:
    """A twin signal that rises slowly and faster towards the end (a bucket filling), signal units."""
    return 10.0 * (np.arange(steps) / steps) ** 1.5


def _walks(steps: int, rate: float, seeds: range) -> list[np.ndarray]:
    """White noise (SD 1) plus a random walk of increment SD ``rate`` per step, zero at the start, per seed."""
    out = []
    for k in seeds:
        rng = np.random.default_rng([31, k])
        out.append(rng.standard_normal(steps) + np.cumsum(rate * rng.standard_normal(steps)))
    return out


def test_the_restricted_likelihood_without_regressors_is_the_level_likelihood() -> None:
    """Two routes to one number: the general Kalman filter (level, AR(1) part and regression coefficients) with no
    regressor gives the likelihood of the two-state filter with a diffuse level, at every walk rate; a regressor
    that is a constant adds only its own diffuse prior, the same at every rate, so the rate it picks is the same."""
    rng = np.random.default_rng(1)
    x = np.cumsum(rng.normal(0.0, 0.3, 120)) + rng.normal(0.0, 1.0, 120)
    short, q = ChannelNoise(1.0, 0.6, 0.5), np.array([0.0, 0.01, 0.1, 1.0])
    plain = level_loglik(x, short, q)
    np.testing.assert_allclose(regression_loglik(x, short, q, np.zeros((120, 0))), plain, rtol=1e-12)
    assert plain[1] > plain[0]  # the walk in x is found
    constant = regression_loglik(x, short, q, np.ones((120, 1)))
    assert int(np.argmax(constant)) == int(np.argmax(plain))


def test_a_walk_beside_a_ramp_keeps_its_rate() -> None:
    """150 steps, walk 0.3 per step: the median rate over 12 seeds within 25 % of the truth (the regression-first
    estimate, which lets the ramp take part of the walk, gives 0.215: 28 % low)."""
    ramp = _ramp(150)
    rates = [estimate_drift(w, ChannelNoise(1.0), ramp)[0] for w in _walks(150, 0.3, range(12))]
    assert abs(np.log(np.median(rates) / 0.3)) < np.log(1.25), rates
    first = [estimate_drift(_unexplained_by(w[:, None], ramp[:, None])[:, 0], ChannelNoise(1.0))[0]
             for w in _walks(150, 0.3, range(12))]
    assert np.median(rates) > np.median(first)


def test_a_short_walk_beside_a_ramp_is_found() -> None:
    """100 steps, walk 0.5 per step: found in at least 11 of 12 seeds (regression first: 9)."""
    ramp = _ramp(100)
    found = [estimate_drift(w, ChannelNoise(1.0), ramp)[0] > 0 for w in _walks(100, 0.5, range(12))]
    assert sum(found) >= 11, found


def test_a_gain_on_the_ramp_is_not_a_walk() -> None:
    """A gain error (0.3 × the twin's ramp) under white noise: a discrepancy, never read as drift."""
    ramp = _ramp(150)
    rng = np.random.default_rng(3)
    fits = [estimate_drift(0.3 * ramp + rng.standard_normal(150), ChannelNoise(1.0), ramp)[0] for _ in range(12)]
    assert not any(f > 0 for f in fits), fits
    channels = sensor_noise((0.3 * ramp + rng.standard_normal(150))[:, None], np.array([10.0]), ramp[:, None])
    assert channels[0].drift == 0.0


def test_a_constant_twin_signal_adds_no_regressor() -> None:
    """A twin channel that does not move (all zeros, or a constant) gives the same drift as no twin at all."""
    w = _walks(100, 0.3, range(1))[0]
    plain = estimate_drift(w, ChannelNoise(1.0))
    assert estimate_drift(w, ChannelNoise(1.0), np.zeros(100)) == plain
    assert estimate_drift(w, ChannelNoise(1.0), np.full(100, 3.0)) == plain


@pytest.mark.slow
@pytest.mark.parametrize("family, seed, index", [("ar1", 0, 5), ("ar1", 1, 12)])
def test_coloured_benchmark_nulls_stay_clean(family: str, seed: int, index: int) -> None:
    """Benchmark nulls (native, nothing planted) whose AR(1) noise (ρ 0.92 over 56 steps, ρ 0.73 over 60) read as
    white and gave `unexplained[m_load]` and `sensor_gain[V1]` with the regression-first drift estimate."""
    case = make_case(index, seed, families=(family,), conditions=("native",))
    result = run_case(case)
    assert not result.get("error"), result.get("error")
    assert result["named"] == [], result["named"]


@pytest.mark.slow
def test_a_gain_under_white_noise_is_still_named() -> None:
    """Benchmark single effect (white noise, native): a −5.5 % gain on F31 stays named, top-1."""
    case = make_case(8, 0, families=("white",), conditions=("native",))
    result = run_case(case)
    assert not result.get("error"), result.get("error")
    assert result["named"] and tuple(result["named"][0]) == ("sensor_gain", "F31"), result["named"]


def test_a_walk_along_the_twin_is_not_taken_for_a_sensor_gain() -> None:
    """On channels whose noise drifts (walk 0.5 per step over 150 steps beside rising twin signals), a gain is
    tried only when it gains OFFSET_EVIDENCE times what a gain gains in the null runs (a walk along a rising
    signal gains much there): never for the walk alone; on a channel that does not drift, always."""
    steps, channels = 150, 4
    t = np.arange(steps)
    twin = np.stack([_ramp(steps) * (1 + 0.5 * j) + 3.0 * np.sign(np.sin(2 * np.pi * t / (12 + 3 * j)))
                     for j in range(channels)], axis=1)
    walk = np.stack(_walks(steps, 0.5, range(channels)), axis=1)
    names = tuple(f"s{j}" for j in range(channels))
    noise, _, _, _ = null_from_arrays(names, walk, np.zeros((8, steps, channels)), np.full(channels, 10.0), twin,
                                   windows(np.array(["dig"] * steps)), np.random.default_rng(1))
    assert noise.gain_null is not None
    drifting = [j for j, c in enumerate(noise.channels) if c.drift > 0]
    assert len(drifting) >= 2, noise.channels
    evidence = noise.gain_evidence(walk, twin)
    for j in range(channels):
        bar = OFFSET_EVIDENCE * max(1.0, float(noise.gain_null[j]))
        if j in drifting:
            assert not _gain_credible(noise, j, float(evidence[j]))
            assert "sensor_gain not named" in noise.withheld[names[j]]
            assert _gain_credible(noise, j, 1.01 * bar) and not _gain_credible(noise, j, 0.99 * bar)
        else:
            assert _gain_credible(noise, j, 0.0)


def _walk_records(seed: int, steps: int, rate: float, channels: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """(residual, twin): white noise (SD 1) plus a random walk of ``rate`` per step on every channel, and rising
    twin signals."""
    rng = np.random.default_rng([47, seed])
    walk = rng.standard_normal((steps, channels)) + np.cumsum(rate * rng.standard_normal((steps, channels)), axis=0)
    return walk, np.stack([_ramp(steps) * (1 + 0.5 * j) for j in range(channels)], axis=1)


def _both(residual: np.ndarray, twin: np.ndarray, seed: int) -> tuple[list[str], list[str], set[str]]:
    """Signals located with the plain whitening, with the drift's whitening, and the drifting signals."""
    steps, channels = residual.shape
    names = tuple(f"s{j}" for j in range(channels))
    wins = windows(np.array(["dig"] * steps))
    noise, calib, _, drift = null_from_arrays(names, residual, np.zeros((8, steps, channels)),
                                              np.full(channels, 10.0), twin, wins, np.random.default_rng([seed, 7919]))
    t = np.arange(steps, dtype=float)
    plain = locate(noise.whiten(residual), t, wins, names, calib).located
    drifted = locate(np.nan_to_num(noise.whiten_drift(residual)), t, wins, names, drift).located
    return [loc.signal for loc in plain], [loc.signal for loc in drifted], set(noise.drifting)


def test_a_walk_that_went_further_than_its_estimate_is_drift() -> None:
    """Walks of 0.4 per step over 60 steps: the whitening without the drift locates most records (a walk's rate is
    known only roughly from one record); with the drift in the whitening, at most 2 of 12 keep a located window."""
    plain, drifted = 0, 0
    for k in range(12):
        p, d, _ = _both(*_walk_records(k, 60, 0.4), seed=k)
        plain += bool(p)
        drifted += bool(d)
    assert plain >= 6, plain  # what the rule is for: without it these nulls would read as unexplained
    assert drifted <= 2, drifted


def test_a_box_on_a_drifting_channel_still_shows_through_the_drift_whitening() -> None:
    """A discrepancy of 4 noise SDs over 10 steps on a drifting channel is still located with the drift in the
    whitening in at least 6 of 8 records (its onset and end are not a walk's increments)."""
    hits = 0
    for k in range(8):
        residual, twin = _walk_records(k, 120, 0.2)
        residual[50:60, 2] += 4.0
        _, d, _ = _both(residual, twin, seed=k)
        hits += "s2" in d
    assert hits >= 6, hits


def test_a_drifting_null_log_is_put_down_to_drift_before_any_search() -> None:
    """Benchmark seed 19 case 19 (a null log, nothing planted, drifting 1.3 % of range; native rate with its seed):
    one window of ``y_b`` late in the dig is located on the drift's wandering level. The search named viscous
    damping in the tilt cylinder for it (some effect removes enough of a small excess); the drift, whitened in,
    explains that window, so nothing is searched and nothing named."""
    case = make_case(19, 19)
    nominal, _ = simulate(case.twin, [], case.twin.seed)
    ranges = {k: channel_range(v) for k, v in nominal.signals.items()}
    rec = field_recording(nominal, nominal.dt, case.noise, case.condition, ranges, 0)
    d = diagnose(rec.noisy, case.twin, options=DiagnoseOptions(progress=None))
    assert d.located, "the case no longer locates anything: the gate is not exercised"
    assert d.effects == [], [e.effect for e in d.effects]
    assert set(d.identification.drift) == {loc.signal for loc in d.located}


def test_offset_deviations_are_the_twin_read_off_its_time_to_first_order() -> None:
    """Two routes to one residual: reading a smooth twin signal δt late (``fieldlog.delayed``, cubic
    interpolation) against ``−δt · ẏ``; and the draws' spread is the one asked for."""
    from discrepancy.data.fieldlog import delayed
    from discrepancy.stats.null import offset_deviations

    dt, t = 0.1, np.arange(200) * 0.1
    twin = np.stack([np.sin(0.7 * t), 3.0 * np.cos(0.3 * t) + 0.1 * t], axis=1)  # (steps, signals)
    dev = offset_deviations(twin, dt, 0.01, 400, np.random.default_rng(4))
    assert dev.shape == (400, *twin.shape)
    # every run is one draw δ times −ẏ: recover δ from the first signal and compare with the delayed read
    rate = np.gradient(twin, dt, axis=0)
    inner = slice(5, -5)
    for k in (0, 1, 2):
        delta = -float(np.sum(dev[k, inner, 0] * rate[inner, 0]) / np.sum(rate[inner, 0] ** 2))
        late = np.stack([delayed(twin[:, j], dt, delta) for j in range(2)], axis=1) - twin
        np.testing.assert_allclose(dev[k, inner], late[inner], atol=2e-3 * abs(delta) / 0.01 + 1e-9)
    deltas = -np.sum(dev[:, inner, 0] * rate[inner, 0], axis=1) / np.sum(rate[inner, 0] ** 2)
    assert np.std(deltas) == pytest.approx(0.01, rel=0.15)


@pytest.mark.slow
def test_an_offset_the_log_leaves_open_is_part_of_the_null() -> None:
    """Benchmark null of seed 27 case 19 (WA475, white noise 2.4 %, the log 0.09 s behind its commands, no seed):
    the offset fitted, 0.06 s, did not halve the misfit and was not undone; replayed on the log's times the lift
    speed's samples at its valve's switches differed by most of a switch and were `unexplained`. The null now
    carries an offset that size (``TwinSpec.offset_spread``): clean."""
    result = run_case(make_case(19, 27))
    assert not result.get("error"), result.get("error")
    assert result["named"] == [], result["named"]
