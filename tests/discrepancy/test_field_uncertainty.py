"""What a log without seed leaves uncertain, and the null that carries it (issue 14): the sensor filter fitted
jointly with the start, the start's draws, the commands' switching times of a resampled log."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import pytest

from discrepancy import RecordingError, TwinSpec
from discrepancy.bench.cases import make_case
from discrepancy.bench.run import run_case
from discrepancy.bench.synth import simulate, simulate_between
from discrepancy.data.episode import EpisodeData, signal_spread
from discrepancy.data.fieldlog import (
    InputReport,
    _held_means,
    command_timing,
    delayed,
    first_order_filter,
    jittered_commands,
    moved_commands,
    resample_commands,
)
from discrepancy.pipeline import DiagnoseOptions, StartCheck, diagnose
from discrepancy.report.document import markdown, text_report, to_json
from discrepancy.twin.align import _compared_rows
from discrepancy.twin.plant import Plan
from discrepancy.twin.runner import SerialRunner
from discrepancy.twin.spec import SimResult, Simulator
from discrepancy.twin.start import PILE, StartEstimate, estimate_start, pile_shift, refit_whole_log
from scaletwin_envs.specs import make_loader, make_soil

DT = 0.1  # s, the ER12's control step


def test_filter_of_channels_at_once_equals_one_channel_at_a_time() -> None:
    rng = np.random.default_rng(3)
    x = np.cumsum(rng.standard_normal((4, 200)), axis=1)
    together = first_order_filter(x, DT, 0.23)
    for j in range(4):
        np.testing.assert_allclose(together[j], first_order_filter(x[j], DT, 0.23), rtol=0, atol=1e-12)


@pytest.mark.parametrize("shift", [0.3, -0.45, 0.0])
def test_a_moved_command_change_is_what_resampling_a_moved_switch_gives(shift: float) -> None:
    """Two routes to one command row: moving a change by a share of a control step (``moved_commands``) equals
    resampling (``resample_commands``) a 1 kHz log whose switch happened that share of a step later."""
    steps = 12
    commands = np.zeros((steps, 3))
    commands[5:, 0], commands[5:, 1], commands[8:, 2] = 0.8, -0.4, 1.0
    h = DT / 100
    fine = np.arange(1, steps * 100 + 1) * h  # the logger's timestamps; row k covers ((k - 1) dt, k dt]
    switch = {0: 5 + shift, 1: 5 + shift, 2: 8.0}  # steps: where each input's change happened
    logged = np.stack([np.where(fine > switch[i] * DT + 1e-9, commands[-1, i], 0.0) for i in range(3)], axis=1)
    grid = np.arange(1, steps + 1) * DT
    route_resample, timing = resample_commands(fine, logged, grid, DT)
    shifts = np.zeros(steps - 1)
    shifts[4] = shift  # the change into row 5
    np.testing.assert_allclose(moved_commands(commands, shifts), route_resample, atol=1e-9)
    # a switch inside a step shows as samples of one interval that disagree: known to half a logger step
    assert timing == (pytest.approx(0.5 * h / DT) if shift else 0.0)


@pytest.mark.parametrize(("rate_hz", "phase"), [(50.0, 0.0), (50.0, 0.37), (200.0, 0.81), (26.9, 0.5)])
def test_commands_switching_on_the_control_grid_come_back_exactly_at_any_logger_phase(rate_hz: float,
                                                                                      phase: float) -> None:
    """A logger reads the command at its sampling instants: at a rate not commensurate with the control step
    (0.0378 s, the miniature's) and at any phase against it, the commands of a controller that switches on the
    control grid come back exactly, and the log says their timing is exact. Holding each sample back over the
    logger's step put up to h/dt of a change into the wrong step (the previous rule; checked to be off here)."""
    dt, steps = 0.0378, 40
    rng = np.random.default_rng(int(rate_hz * 10 + phase * 100))
    commands = np.clip(np.cumsum(rng.normal(0.0, 0.3, (steps, 3)), axis=0), -1.0, 1.0)  # a change every step
    grid = dt * np.arange(1, steps + 1)  # row k ends its interval ((k - 1) dt, k dt]
    h = 1.0 / rate_hz
    t = grid[0] + h * (phase + np.arange(int((grid[-1] - grid[0]) / h)))  # the logger's clock, its own phase
    t = np.concatenate(([grid[0]], t[t > grid[0] + 1e-9]))  # its first sample ends the first control step
    logged = commands[np.ceil(t / dt - 1e-6).astype(int) - 1]  # the command in force at each sampling instant
    back, timing = resample_commands(t, logged, grid[grid <= t[-1] + 1e-12], dt)
    np.testing.assert_allclose(back, commands[:len(back)], rtol=0, atol=1e-12)
    assert timing == 0.0
    assert np.max(np.abs(_held_means(t, logged, grid[:len(back)], dt) - commands[:len(back)])) > 0.05


def test_an_interval_without_a_sample_takes_the_held_mean() -> None:
    """A jittered logger just above the control rate can leave a control interval without a sample: that row
    takes the time-weighted mean of the samples held over their logger steps (what the interval saw)."""
    t = np.array([0.1, 0.19, 0.31, 0.39, 0.5])  # nothing in (0.2, 0.3]
    logged = np.array([[0.0], [0.5], [1.0], [1.0], [-1.0]])
    grid = np.array([0.1, 0.2, 0.3, 0.4, 0.5])
    back, _ = resample_commands(t, logged, grid, DT)
    np.testing.assert_allclose(back[:, 0], [0.0, 0.5, 1.0, 1.0, -1.0], atol=1e-12)


def test_command_timing_is_the_logs_and_a_native_log_has_none() -> None:
    assert command_timing(None) == 0.0
    assert command_timing(InputReport(10.0, DT, resampled=False, command_timing=0.3)) == 0.0
    assert command_timing(InputReport(50.0, DT, resampled=True)) == 0.0  # switching on the grid: exact
    assert command_timing(InputReport(50.0, DT, resampled=True, command_timing=0.1)) == pytest.approx(0.1)
    rng = np.random.default_rng(0)
    cmds = np.repeat(np.array([[0.0, 0.2, -1.0], [1.0, 0.2, -1.0], [1.0, -0.6, 0.5]]), 4, axis=0)
    moved = jittered_commands(cmds, 0.1, rng)
    assert np.all(np.abs(moved - cmds) <= 0.1 * 1.6 + 1e-12)  # at most the timing times the largest change
    assert np.all(moved[:3] == cmds[:3]) and not np.array_equal(moved, cmds)
    np.testing.assert_array_equal(jittered_commands(cmds, 0.0, rng), cmds)


#: A pile off the nominal one (boom lengths), read through a first-order sensor filter of :data:`TAU` s.
TRUTH = {"pile_distance": 0.47, "pile_height": 0.74}
TAU = 0.2
STEPS = 50


PARTS = 5  # readings per control step between the steps (``TwinDigEnv.read_between``)


@pytest.fixture(scope="module")
def dig() -> tuple[TwinSpec, EpisodeData, dict[str, np.ndarray]]:
    """The nominal twin a user would give, a dig on :data:`TRUTH`'s pile, and that dig read between its control
    steps (what a sensor filter and a late clock act on)."""
    twin = TwinSpec(make_loader("er12"), make_soil("sand"), {}, 0)
    clean, _, between = simulate_between(dataclasses.replace(twin, env_kwargs={"reset_noise_scale": 0.0, **TRUTH}),
                                         [], 3)
    return twin, clean, between.signals


@pytest.fixture(scope="module")
def truth(dig: tuple[TwinSpec, EpisodeData, dict[str, np.ndarray]]) -> tuple[TwinSpec, EpisodeData]:
    """The nominal twin and the first :data:`STEPS` rows of the dig."""
    twin, clean, _ = dig
    return twin, clean.head(STEPS)


def _seedless(clean: EpisodeData, sensor: Callable[[str], np.ndarray], seed: int) -> EpisodeData:
    """``clean`` as a log without seed: each channel as ``sensor`` reads it (by name), plus white noise of 0.3 % of
    its spread."""
    rng = np.random.default_rng(seed)
    spread = signal_spread(clean.signals)
    signals = {k: sensor(k)[: len(v)] + 0.003 * spread[k] * rng.standard_normal(len(v))
               for k, v in clean.signals.items()}
    return dataclasses.replace(clean, signals=signals, seed=None, name="field")


@pytest.fixture(scope="module")
def filtered_log(dig: tuple[TwinSpec, EpisodeData, dict[str, np.ndarray]]) -> tuple[TwinSpec, EpisodeData]:
    """The first rows through a sensor filter of :data:`TAU` s acting between the control steps."""
    twin, clean, fine = dig
    return twin, _seedless(clean.head(STEPS),
                           lambda k: first_order_filter(fine[k], DT / PARTS, TAU)[PARTS - 1::PARTS], 5)


def test_start_and_sensor_filter_estimated_together(filtered_log: tuple[TwinSpec, EpisodeData]) -> None:
    """Through its filter the log lags; fitted jointly, the filter comes out right and the pile stays where it is
    (fitted on the unfiltered twin, a nearer pile makes up for part of the lag)."""
    twin, ep = filtered_log
    est = estimate_start(ep, SerialRunner(twin), profile_filter=True)
    got = dict(est.options)
    assert est.sensor_tau == pytest.approx(TAU, rel=0.25)
    assert got["pile_distance"] == pytest.approx(TRUTH["pile_distance"], rel=0.02)
    assert 0 < est.rows < STEPS  # fitted on the rows up to and a little after the contact
    # the null's starts: around the estimate, each pile quantity moved, none beyond the env's bounds
    draws = [dict(d) for d in est.draws]
    assert len(draws) >= 8
    for k in PILE:
        values = np.array([d[k] for d in draws])
        assert np.std(values) > 0 and np.all(values > 0)
    unfiltered = estimate_start(ep, SerialRunner(twin))
    assert unfiltered.sensor_tau == 0.0
    assert est.misfit < unfiltered.misfit


OFFSET = 0.25  # s: the log's signals lag its commands by this much


def test_start_and_time_offset_estimated_together(truth: tuple[TwinSpec, EpisodeData],
                                                  dig: tuple[TwinSpec, EpisodeData, dict[str, np.ndarray]],
                                                  filtered_log: tuple[TwinSpec, EpisodeData]) -> None:
    """A log whose clock runs behind its commands: fitted alone, the start takes the lag for a pile met later;
    fitted together, the offset comes out and the pile stays where it is."""
    twin, _ = truth
    _, clean, fine = dig
    late = _seedless(clean.head(STEPS), lambda k: delayed(fine[k], DT / PARTS, OFFSET)[PARTS - 1::PARTS], 9)
    est = estimate_start(late, SerialRunner(twin), fit_offset=True)
    assert est.offset == pytest.approx(OFFSET, abs=0.03)
    assert dict(est.options)["pile_distance"] == pytest.approx(TRUTH["pile_distance"], rel=0.02)
    assert estimate_start(filtered_log[1], SerialRunner(twin), profile_filter=True, fit_offset=True).offset == 0.0


def _late(result: SimResult, offset: float) -> dict[str, np.ndarray]:
    """A replay read between its control steps, delayed by ``offset`` s there and sampled at the steps."""
    assert result.between is not None
    fine_dt = result.between.dt
    parts = round(DT / fine_dt)
    return {k: delayed(v, fine_dt, offset)[parts - 1::parts] for k, v in result.between.signals.items()}


def test_twin_read_at_the_logs_times_is_its_replay_delayed() -> None:
    """Two routes to the twin a late logger sees: a twin spec with ``time_offset`` replays what the plain replay,
    read between its control steps and delayed by ``delayed`` there, gives at the steps."""
    twin = TwinSpec(make_loader("er12"), make_soil("sand"), {}, 2)
    commands = simulate(twin, [], 2)[0].commands[:30]
    plain = Simulator(twin).run(commands, between=True)
    late = SerialRunner(dataclasses.replace(twin, time_offset=0.17)).run_many(commands, [Plan()])[0]
    for k in ("F21", "lift_extension", "travel_speed"):
        np.testing.assert_allclose(late.signals[k], _late(plain, 0.17)[k], rtol=0, atol=1e-9)
    x = np.linspace(0.0, 3.0, 31)
    np.testing.assert_allclose(delayed(2.0 * x, DT, 0.2)[5:], 2.0 * (x[5:] - 0.2), atol=1e-12)  # a ramp, 0.2 s late


def test_a_log_leading_its_commands_ends_with_the_last_command_held() -> None:
    """Two routes to the last rows of a log whose signals lead its commands by 0.17 s: the twin read at the
    log's times runs on with the last command held for the two steps after the log's end (it does not freeze on
    its last sample), which is the plain replay of the commands with those two rows appended, read early."""
    twin = TwinSpec(make_loader("er12"), make_soil("sand"), {}, 2)
    commands = simulate(twin, [], 2)[0].commands[:30]
    longer = np.concatenate((commands, np.repeat(commands[-1:], 2, axis=0)))
    plain = Simulator(twin).run(longer, between=True)
    early = SerialRunner(dataclasses.replace(twin, time_offset=-0.17)).run_many(commands, [Plan()])[0]
    assert early.error is None and len(early.phases) == 30
    for k in ("F21", "lift_extension", "travel_speed"):
        np.testing.assert_allclose(early.signals[k], _late(plain, -0.17)[k][:30], rtol=0, atol=1e-9)
    frozen = delayed(plain.signals["lift_extension"][:30], DT, -0.17)  # the twin's last sample held instead
    assert not np.allclose(early.signals["lift_extension"][-2:], frozen[-2:], rtol=0, atol=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("seed, index", [(0, 5), (2, 0), (9, 19)])
def test_field_log_nulls_stay_clean(seed: int, index: int) -> None:
    """Benchmark nulls delivered as field logs without seed (a 50 Hz WA475 log through per-channel sensor filters;
    an ER12 CSV without ``lift_extension``), which named friction or compliance before the start, filter and
    offset were fitted together and the null drew starts and command timings; and a quantised 50 Hz log of the
    miniature (control step 0.038 s), which located 39 windows and named friction while its commands were taken
    as held over each logger step."""
    result = run_case(make_case(index, seed))
    assert not result.get("error"), result.get("error")
    assert result["named"] == [], result["named"]


def test_a_start_refitted_on_the_whole_log_finds_a_pile_the_early_rows_left_off(
        truth: tuple[TwinSpec, EpisodeData]) -> None:
    """The early rows see the pile's distance better than its slope: from a start whose repose angle is 4° too
    steep, fitted on the first 20 rows, the whole-log refit brings the angle back and fits every row better."""
    twin, clean = truth
    ep = _seedless(clean, lambda k: clean.signals[k], 11)
    steep = {**TRUTH, "boom_angle": 0.0, "bucket_angle": 0.0,
             "repose_angle": twin.soil.repose_angle + np.radians(4.0)}
    early = StartEstimate(tuple(sorted(steep.items())), math.nan, math.nan, 0, rows=20)
    runner = SerialRunner(twin)
    refit = refit_whole_log(ep, runner, early)
    got = dict(refit.options)
    assert abs(got["repose_angle"] - twin.soil.repose_angle) < 0.25 * np.radians(4.0)
    assert refit.rows == len(ep) and refit.replays > 0 and len(refit.draws) >= 8
    assert refit.misfit < 0.5 * refit.misfit_default  # misfit_default: the steep start on every row
    assert pile_shift(runner, refit.options) < pile_shift(runner, early.options) == pytest.approx(2.0)


def test_the_start_check_is_reported_and_validated(filtered_log: tuple[TwinSpec, EpisodeData]) -> None:
    """What a start refitted on the whole log leaves is in the JSON report (schema-valid) and said in the text:
    cleared, the log is consistent with the twin from that start and what the search reached against the early-dig
    start is listed as indistinguishable from the pile; not cleared, the windows are beyond the pile."""
    twin, ep = filtered_log
    d = diagnose(ep, twin, options=DiagnoseOptions(budget=20))
    cases = ((0, False, ("payload_mass_error",), "5 windows are located; a start refitted"),
             (2, False, ("payload_mass_error", "unexplained"), "leaves only 2 faint (put down to chance)"),
             (3, True, (), "the pile alone does not explain them"))
    for after, rest, found, phrase in cases:
        check = StartCheck({"pile_distance": 0.47, "repose_angle": 0.6}, 5, after, 40, 0.6, found, rest)
        assert check.cleared is not rest
        shown = dataclasses.replace(d, start_check=check, effects=[] if check.cleared else d.effects)
        doc = to_json(shown)
        assert doc["start_check"] == {"options": {"pile_distance": 0.47, "repose_angle": 0.6}, "located_before": 5,
                                      "located_after": after, "replays": 40, "pile_shift": 0.6,
                                      "indistinguishable": list(found), "strong_rest": rest}
        text = " ".join(text_report(shown, width=400).split())
        assert phrase in text
        if check.cleared:
            assert "so nothing is named" in text
            assert "reached payload_mass_error: this log cannot tell it from that pile" in text
            assert "No effect named: what was located is the pile's (a start refitted on the whole log" in text
            assert "No effect is named: what was located is the pile's" in markdown(shown)
            assert "start pose and pile estimated from the log (it has no reset seed)" in markdown(shown)




def test_a_null_log_without_seed_names_nothing() -> None:
    """Benchmark null of seed 41 case 0 (λ 1.45 on sand, 8-bit quantised 50 Hz log, no seed). With the start draws
    of 0.2 half-ranges in every direction, one window of the bucket's angular speed was located in the pull-back
    against the start fitted on the early dig, and only the start refitted on the whole log cleared it; with the
    draws following what the fitted rows allow (``twin.start.SHAPE_LR``) nothing is located at all. Either way the
    log is consistent with the twin and nothing is named; where the check runs, it clears."""
    case = make_case(0, 41)
    assert case.kind == "null" and case.condition.field_log
    result = run_case(case)
    assert not result.get("error"), result.get("error")
    assert result["named"] == [] and not result["unexplained"]
    check = result["start_check"]
    assert check is None or check["located_after"] == 0 or not check["strong_rest"]


def test_a_log_leading_its_commands_is_compared_only_where_its_commands_are_known() -> None:
    """A log whose signals lead its commands by 0.17 s reads, on its last two rows, the machine under two commands
    that come after its last row (the pull-back of a dig that the logger's window cut). Those rows are not
    compared; their commands become the twin's ``command_tail``, so that the rows kept are, to the bit, the replay
    of every logged command read early (two routes), not the replay with the last kept command held."""
    twin = TwinSpec(make_loader("er12"), make_soil("sand"), {}, 2)
    commands = simulate(twin, [], 2)[0].commands[:30].copy()
    commands[28:] = [0.0, 0.0, -1.0]  # the last two rows: the lift stops and the machine reverses
    truth = Simulator(twin).run(commands, between=True)
    early = dataclasses.replace(twin, time_offset=-0.17)
    log = EpisodeData(DT * np.arange(1, 31), commands, _late(truth, -0.17), truth.phases, None)
    notes: list[str] = []
    kept, spec = _compared_rows(log, early, notes)
    assert len(kept) == 28 and np.array_equal(np.asarray(spec.command_tail), commands[28:])
    assert "the last 2 rows" in notes[0]
    replay = SerialRunner(spec).run_many(kept.commands, [Plan()])[0]
    held = SerialRunner(early).run_many(kept.commands, [Plan()])[0]  # the last kept command held instead
    for k in ("lift_extension", "travel_speed", "F21"):
        np.testing.assert_allclose(replay.signals[k], log.signals[k][:28], rtol=0, atol=1e-9)
    assert not np.allclose(held.signals["travel_speed"][-1:], log.signals["travel_speed"][27:28], rtol=0, atol=1e-3)
    assert _compared_rows(log, twin, [])[0] is log  # no lead: nothing dropped
    with pytest.raises(RecordingError, match="leaves 8 of its 30 rows"):
        _compared_rows(log, dataclasses.replace(twin, time_offset=-2.15), [])
