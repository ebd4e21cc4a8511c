"""The benchmark's truth: where a planted effect shows is judged on what the case's sensors deliver (filtered,
offset, resampled alike for the planted and the nominal twin), under the covariance of the planted noise."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from discrepancy.bench.cases import make_case
from discrepancy.bench.logs import Condition
from discrepancy.bench.scoring import SHOWS, noise_covariance, truth_pairs
from discrepancy.bench.sensor_noise import DRIFT_REF_S, TAU_RANGE, WHITE_SHARE, NoiseSpec, channel_range
from discrepancy.bench.synth import aligned, field_recording, nominal_replay, simulate_between
from discrepancy.data.channels import COMPARED
from discrepancy.data.episode import signal_spread
from discrepancy.effects import Effect, Scales


@pytest.fixture(scope="module")
def dig():
    """An ER12 dig cycle (the benchmark's case 0 of seed 1, its twin) recorded between the control steps."""
    twin = make_case(0, 1).twin
    clean, control_dt, between = simulate_between(twin, [], twin.seed)
    return twin, clean, control_dt, between


def test_nominal_replay_is_the_closed_loop_recording(dig) -> None:
    """Two routes to one trajectory: the scripted dig in closed loop, and its commands replayed open loop from the
    same reset seed, give the same signals to the bit (the truth's reference needs nothing else)."""
    twin, clean, _, between = dig
    ep, replayed = nominal_replay(twin, clean)
    for k in COMPARED:
        np.testing.assert_array_equal(ep.signals[k], clean.signals[k])
        np.testing.assert_allclose(replayed.signals[k], between.signals[k], rtol=0, atol=0)


def test_a_perfect_twin_shows_nowhere_through_a_filter_and_an_offset(dig, tmp_path: Path) -> None:
    """Nothing planted, a 200 Hz log 0.07 s late through 0.05–0.3 s sensor filters: nothing shows. Against the
    control-step truth (unfiltered, on the commands' clock) the same reading differs far beyond noise."""
    twin, clean, control_dt, between = dig
    names = tuple(COMPARED)
    ranges = {k: channel_range(v) for k, v in clean.signals.items()}
    rng = np.random.default_rng(5)
    taus = tuple((c, float(rng.uniform(*TAU_RANGE))) for c in names)
    noise = NoiseSpec("lowpass", 0.005, taus=taus, seed=3)
    cond = Condition("200hz", rate_hz=200.0, offset_s=0.07)
    real = field_recording(clean, control_dt, noise, cond, ranges, 0, tmp_path / "real", between)
    ref_clean, ref_between = nominal_replay(twin, real.clean)
    reference = field_recording(ref_clean, control_dt, noise, cond, ranges, 0, tmp_path / "nominal", ref_between)
    assert real.reading is not None
    time = real.reading.time
    present = tuple(s for s in names if s in real.reading.signals)
    spread = np.zeros((len(time), len(present)))
    shows, faint = truth_pairs(real, reference, time, present, spread, noise, ranges)
    assert shows == set() and faint == set()
    # the old reference, the truth on the commands' clock without the sensors, is far off the reading
    unfiltered = aligned(real.clean, time)
    lam = max(float(np.nansum(((real.reading.signals[s] - unfiltered.signals[s]) / real.noise_sd[s]) ** 2))
              for s in present)
    assert lam > 100 * SHOWS


def test_a_planted_effect_shows_through_the_same_chain(dig, tmp_path: Path) -> None:
    """A 20 % heavier payload read through the same filtered, late log shows on the payload's signals."""
    twin, clean, control_dt, _ = dig
    scales = Scales.of(twin.loader, twin.soil, signal_spread(clean.signals))
    effect = Effect.from_pi("payload_mass_error", "payload", {"mass_error": 0.2}, scales)
    planted_clean, _, planted_between = simulate_between(twin, [effect], twin.seed)
    ranges = {k: channel_range(v) for k, v in clean.signals.items()}
    noise = NoiseSpec("white", 0.005, seed=4)
    cond = Condition("offset", offset_s=0.05)
    real = field_recording(planted_clean, control_dt, noise, cond, ranges, 0, tmp_path / "real", planted_between)
    ref_clean, ref_between = nominal_replay(twin, real.clean)
    reference = field_recording(ref_clean, control_dt, noise, cond, ranges, 0, tmp_path / "nominal", ref_between)
    assert real.reading is not None
    present = tuple(s for s in COMPARED if s in real.reading.signals)
    spread = np.zeros((len(real.reading.time), len(present)))
    shows, _ = truth_pairs(real, reference, real.reading.time, present, spread, noise, ranges)
    assert {"m_load", "F21"} & {s for s, _ in shows}


@pytest.mark.parametrize("rho", [0.0, 0.5, 0.9])
def test_ar1_covariance_matches_the_closed_form_precision(rho: float) -> None:
    """A constant difference over n rows under AR(1) noise: 1' C⁻¹ 1 = [2 + (n−2)(1+ρ²) − 2(n−1)ρ] / (σ²(1−ρ²)),
    n/σ² for white noise; the stronger the colour, the less evidence."""
    n, sd = 10, 0.3
    noise = NoiseSpec("ar1", 0.01, rho=rho)
    cov = noise_covariance(noise, "F21", 1.0, sd, np.arange(n) * 0.1, 0.1, 0.1)(np.arange(n))
    ones = np.ones(n)
    expected = (2 + (n - 2) * (1 + rho**2) - 2 * (n - 1) * rho) / (sd**2 * (1 - rho**2))
    assert float(ones @ np.linalg.solve(cov, ones)) == pytest.approx(expected, rel=1e-9)


def test_drift_covariance_is_the_random_walk_beside_its_white_share() -> None:
    """Variance at t: (a·span)² t / t_ref + (WHITE_SHARE·a·span)² / samples per step; covariance min(t_i, t_j)."""
    noise = NoiseSpec("drift", 0.02, amplitudes=(("F21", 0.01),))
    span, dt, h = 5e4, 0.1, 0.02
    elapsed = dt * np.arange(50)
    cov = noise_covariance(noise, "F21", span, 0.0, elapsed, dt, h)(np.arange(20, 30))
    amp = 0.01 * span
    np.testing.assert_allclose(np.diag(cov), amp**2 * elapsed[20:30] / DRIFT_REF_S + (WHITE_SHARE * amp) ** 2 / 5)
    assert cov[0, 5] == pytest.approx(amp**2 * elapsed[20] / DRIFT_REF_S)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
