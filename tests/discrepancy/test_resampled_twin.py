"""A log sampled faster than the control step against a twin read between its control steps and resampled alike.

Physical meaning: reading the twin between its control steps is a measurement, so it must not change the physics
(the control-step signals stay the same to the bit); a perfect twin seen through the same resampling as a 500 Hz
log of the same machine gives that log back (two routes to the same samples), while its control-step samples
alone miss what happens inside a step (a force jumping as a cylinder reaches relief).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from discrepancy.bench.logs import Condition, resample
from discrepancy.bench.sensor_noise import lowpass
from discrepancy.bench.synth import simulate_between
from discrepancy.data.channels import COMPARED
from discrepancy.data.episode import EpisodeData
from discrepancy.data.fieldlog import (
    delayed,
    estimate_channel_taus,
    estimate_sensor_tau,
    first_order_filter,
    prepare_log,
    resample_signal,
    resampling_operator,
)
from discrepancy.twin.env import Structure
from discrepancy.twin.plant import Plan
from discrepancy.twin.runner import SerialRunner
from discrepancy.twin.spec import Simulator, TwinSpec
from discrepancy.twin.start import _Fit, misfit


@pytest.fixture(scope="module")
def truth(twin: TwinSpec):
    return simulate_between(twin, [], twin.seed)


def test_reading_between_the_control_steps_changes_nothing(twin: TwinSpec, truth) -> None:
    clean, dt, between = truth
    sim = Simulator(twin)
    plain, read = sim.run(clean.commands), sim.run(clean.commands, between=True)
    assert plain.between is None and read.between is not None
    parts = round(dt / read.between.dt)
    assert parts == 5 and abs(parts * read.between.dt - dt) < 1e-12
    for k in ("F21", "Pf_lift", "lift_extension", "a1"):
        assert np.array_equal(plain.signals[k], read.signals[k])  # the same physics, to the bit
        assert np.array_equal(read.between.signals[k][parts - 1::parts], read.signals[k])
        assert np.array_equal(read.signals[k], clean.signals[k])  # the closed loop's, replayed
        assert np.array_equal(read.between.signals[k], between.signals[k])  # and the generator's in between


@pytest.mark.parametrize(("steps", "dt", "h", "tail", "tau"), [
    (120, 0.1, 0.002, 0.04, 0.0), (90, 0.0378, 0.02, 0.0, 0.0), (40, 0.1, 0.005, 0.5, 0.0),
    (120, 0.1, 0.002, 0.0, 0.15)])
def test_the_resampling_operator_is_the_logs_resampling(steps: int, dt: float, h: float, tail: float,
                                                        tau: float) -> None:
    parts = 5
    span = (steps - 1) * dt - tail  # a log that ends before the last control step leaves it as it is
    y = np.cumsum(np.random.default_rng(steps).standard_normal(steps * parts))
    fine_t = dt / parts * np.arange(1, steps * parts + 1)
    log_t = dt + h * np.arange(int(np.floor(span / h + 1e-9)) + 1)
    grid = dt * np.arange(1, steps + 1)
    seen = grid <= log_t[-1] + 1e-9
    sensed = CubicSpline(fine_t, y)(log_t)
    sensed = first_order_filter(sensed, h, tau) if tau else sensed  # the sensor filters the signal, then it is logged
    direct = resample_signal(log_t, sensed, grid[seen], dt)
    op = resampling_operator(steps, parts, dt, h, span, tau)
    assert op.shape == (steps, steps * parts)
    got = op @ y
    assert np.max(np.abs(got[seen] - direct)) < 1e-10 * np.ptp(y)
    assert np.array_equal(got[~seen], y[parts - 1::parts][~seen])
    # each row weighs a few control steps either side of its own, and a constant stays itself
    assert np.allclose(op @ np.ones(steps * parts), 1.0, atol=1e-9)


@pytest.mark.parametrize("tau", [0.0, 0.16])
def test_a_perfect_twin_resampled_alike_gives_a_fast_log_back(twin: TwinSpec, truth, tau: float) -> None:
    """Also through a sensor filter (each channel's signal filtered as it is, then logged at 500 Hz): a filter
    applied to the twin's readings instead (linear between them) left an acceleration up to its range off."""
    clean, dt, between = truth
    signals = {k: clean.signals[k] for k in COMPARED if k in clean.signals}
    log = resample(clean.time, clean.commands, signals, Condition("500hz", rate_hz=500.0), dt, between)
    logged = {k: first_order_filter(v, log.h, tau) for k, v in log.truth.items()} if tau else log.truth
    prepared = prepare_log(log.time, log.commands, logged, np.full(len(log.time), "", dtype=object), dt)
    report = prepared.report
    assert report.resampled and report.span_s == pytest.approx(log.time[-1] - log.time[0])
    n = len(prepared.time)
    alike = dataclasses.replace(twin, log_step=1.0 / report.original_rate_hz, log_span=report.span_s, sensor_tau=tau)
    assert TwinSpec.from_dict(alike.to_dict()) == alike  # what a saved twin file carries
    seen = Simulator(alike).run(prepared.commands)
    plain = Simulator(dataclasses.replace(twin, sensor_tau=tau)).run(prepared.commands)
    between_only = Simulator(alike).run(prepared.commands, between=True).between
    assert between_only is not None
    worst = {name: max(np.max(np.abs(out[k][:n] - prepared.signals[k])) / np.ptp(signals[k]) for k in signals)
             for name, out in (("alike", seen.signals), ("plain", plain.signals))}
    assert worst["alike"] < 1e-6
    assert worst["plain"] > 0.05  # the control-step samples alone: a jump inside a step spread over its neighbours
    if tau:  # the readings filtered, then resampled: the filter must act between them
        op = resampling_operator(len(prepared.commands) + 1, 5, dt, alike.log_step, alike.log_span)
        inner = n - 5  # away from the last row, which reads a step the readings do not cover
        read_filtered = max(np.max(np.abs((op @ np.append(between_only.signals[k], np.zeros(5)))[:inner]
                                          - prepared.signals[k][:inner])) / np.ptp(signals[k])
                            for k in ("a1", "alpha1"))
        assert read_filtered > 0.05


def test_a_replay_of_the_first_rows_stops_where_its_resampling_needs(twin: TwinSpec, truth) -> None:
    """A start fit replays a resampled log's first rows plus the resampling's reach: those rows come out as in the
    whole replay, and the replay stops there (running every such replay on to the log's end had doubled the start
    fit's time on 50-500 Hz logs)."""
    clean, dt, between = truth
    signals = {k: clean.signals[k] for k in COMPARED if k in clean.signals}
    log = resample(clean.time, clean.commands, signals, Condition("200hz", rate_hz=200.0), dt, between)
    prepared = prepare_log(log.time, log.commands, log.truth, np.full(len(log.time), "", dtype=object), dt)
    alike = dataclasses.replace(twin, log_step=1.0 / prepared.report.original_rate_hz,
                                log_span=prepared.report.span_s)
    sim = Simulator(alike)
    whole = sim.run(prepared.commands)
    end = sim.env(Structure()).data.time
    rows = 30
    replayed = rows + alike.resampling_reach(dt)
    assert replayed < len(prepared.commands) - 10
    first = sim.run(prepared.commands[:replayed])
    assert sim.env(Structure()).data.time == pytest.approx(replayed * dt)
    assert end > (len(prepared.commands) - 1) * dt
    worst = max(np.max(np.abs(first.signals[k][:rows] - whole.signals[k][:rows])) / np.ptp(signals[k])
                for k in signals)
    assert worst < 1e-6


@pytest.mark.parametrize("offset", [0.05, 0.13])
def test_a_perfect_twin_read_late_gives_an_offset_log_back(twin: TwinSpec, truth, offset: float) -> None:
    """A logger whose clock runs late reads the machine between the control steps: the twin read between its own
    steps at the same offset gives the log back (two routes to the same samples), a curve through its control
    samples (what the twin was read on at an offset before) misses a force jumping inside a step."""
    clean, dt, between = truth
    signals = {k: clean.signals[k] for k in COMPARED if k in clean.signals}
    log = resample(clean.time, clean.commands, signals, Condition("offset", offset_s=offset), dt, between)
    late = dataclasses.replace(twin, time_offset=offset)
    assert late.reads_between and not twin.reads_between
    seen = Simulator(late).run(log.commands).signals
    through_samples = {k: delayed(v, dt, offset) for k, v in Simulator(twin).run(log.commands).signals.items()}
    worst = {name: max(np.max(np.abs(out[k] - log.truth[k])) / np.ptp(signals[k]) for k in signals)
             for name, out in (("between", seen), ("samples", through_samples))}
    assert worst["between"] < 1e-6
    assert worst["samples"] > 0.05


def test_a_perfect_twin_filtered_between_its_steps_gives_a_filtered_log_back(twin: TwinSpec, truth) -> None:
    """A sensor filter at the control step acts on the signal between the samples: the benchmark's sensor filters
    the physics at 20 instants a step; the twin, filtered over its readings (5 a step), comes within a fraction of
    a per cent of that log, the twin's control samples filtered alone (a line between them) do not."""
    clean, dt, between = truth
    tau = 0.15
    signals = {k: clean.signals[k] for k in COMPARED if k in clean.signals}
    log = resample(clean.time, clean.commands, signals, Condition("csv"), dt, between, parts=20)
    logged = {k: lowpass(v, dt / 20, tau)[19::20] for k, v in log.fine.items()}
    seen = Simulator(dataclasses.replace(twin, sensor_tau=tau)).run(log.commands).signals
    samples = {k: first_order_filter(v, dt, tau) for k, v in Simulator(twin).run(log.commands).signals.items()}
    worst = {name: np.median([np.max(np.abs(out[k] - logged[k])) / np.ptp(signals[k]) for k in signals])
             for name, out in (("between", seen), ("samples", samples))}
    assert worst["between"] < 0.01
    assert worst["samples"] > 3 * worst["between"]


def test_the_start_fit_reads_a_lead_of_less_than_a_step_between_the_steps(twin: TwinSpec, truth) -> None:
    """A log 0.45 control steps early: the start fit's offset scan, on the twin read between its steps, lands
    within a quarter step of it (whole steps alone read it a whole step off or not at all)."""
    clean, dt, between = truth
    offset = -0.45 * dt
    signals = {k: clean.signals[k] for k in COMPARED if k in clean.signals}
    log = resample(clean.time, clean.commands, signals, Condition("offset", offset_s=offset), dt, between)
    ep = EpisodeData(log.time, log.commands, log.truth, np.full(len(log.time), "", dtype=object), None)
    fit = _Fit(ep, SerialRunner(twin), rows=60, between=True)
    assert fit.between
    replay = SerialRunner(twin).run_many(ep.commands[: fit.replayed], [Plan()], between=True)[0]
    best = fit.best_shift(fit.residuals(replay))
    assert best is not None and abs(best.shift * dt - offset) <= 0.25 * dt + 1e-9
    assert misfit(best) < 0.5 * min(misfit(fit.residuals(replay, float(k))) for k in (-1, 0))


@pytest.mark.parametrize("tau", [0.05, 0.15])
def test_a_sensor_filter_is_estimated_on_the_twin_read_between_its_steps(twin: TwinSpec, truth, tau: float) -> None:
    """A log at the control step through a sensor filter (the physics filtered at 20 instants a step): its time
    constant, common and per channel, is recovered to 2 ms against the twin read between its steps; against the
    control samples alone (a line between them) the common one comes out 0 or > 10 ms off."""
    clean, dt, between = truth
    signals = {k: clean.signals[k] for k in COMPARED if k in clean.signals}
    log = resample(clean.time, clean.commands, signals, Condition("csv"), dt, between, parts=20)
    logged = {k: lowpass(v, dt / 20, tau)[19::20] for k, v in log.fine.items()}
    replay = Simulator(twin).run(log.commands, between=True)
    assert replay.between is not None
    assert estimate_sensor_tau(logged, replay.between.signals, dt, parts=5) == pytest.approx(tau, abs=2e-3)
    own = estimate_channel_taus(logged, replay.between.signals, dt, parts=5)
    assert max(abs(v - tau) for v in own.values()) < 2e-3
    assert abs(estimate_sensor_tau(logged, replay.signals, dt) - tau) > 0.01
