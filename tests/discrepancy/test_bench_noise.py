"""The benchmark's sensor noise families, field logs and case draw (issue 14): each generator has its stated
property, everything is deterministic per seed, a 200 Hz CSV log round-trips through the importer with its units
converted, and a 2-case benchmark runs end to end (slow)."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import numpy as np
import pytest

from discrepancy.bench import sensor_noise as sn
from discrepancy.bench.cases import KIND_PATTERN, MIN_DECADES, RANGES, make_case, make_cases
from discrepancy.bench.logs import LOG_UNITS, Condition, resample, write_csv
from discrepancy.bench.run import parse_label
from discrepancy.bench.scoring import start_check_lines
from scaletwin_envs.recording import import_recording


def test_noise_module_is_independent_of_the_tool() -> None:
    tree = ast.parse(Path(sn.__file__).read_text())
    imported = [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    imported += [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    assert imported and not [m for m in imported if m.startswith("discrepancy")]


def test_white_sd() -> None:
    x = sn.white(np.random.default_rng(1), 50_000, 0.3)
    assert abs(x.std() - 0.3) < 0.01 and abs(np.corrcoef(x[:-1], x[1:])[0, 1]) < 0.02


@pytest.mark.parametrize("rho", [0.5, 0.8, 0.95])
def test_ar1_autocorrelation(rho: float) -> None:
    x = sn.ar1(np.random.default_rng(2), 100_000, 2.0, rho)
    assert abs(np.corrcoef(x[:-1], x[1:])[0, 1] - rho) < 0.01
    assert abs(np.corrcoef(x[:-2], x[2:])[0, 1] - rho**2) < 0.02  # AR(1), not just lag one
    assert abs(x.std() / 2.0 - 1.0) < 0.05  # marginal sd as stated
    with pytest.raises(ValueError):
        sn.ar1(np.random.default_rng(0), 10, 1.0, 1.0)


def test_ar1_rate_keeps_the_correlation_time() -> None:
    """``rho`` is at the control step: a 500 Hz log with dt = 0.1 s has the same correlation at a 0.1 s lag."""
    dt, h = 0.1, 0.002
    spec = sn.NoiseSpec("ar1", 0.01, rho=0.7, seed=3)
    t = np.arange(200_000) * h
    n = sn.apply_noise(spec, {"F21": np.zeros_like(t)}, h, dt, {"F21": 100.0}).noise["F21"]
    lag = round(dt / h)
    assert abs(np.corrcoef(n[:-lag], n[lag:])[0, 1] - 0.7) < 0.05


def test_random_walk_variance_grows_linearly() -> None:
    rng = np.random.default_rng(4)
    walks = np.stack([sn.random_walk(rng, 400, 0.05, sd_ref=1.0, t_ref=10.0) for _ in range(3000)])
    t = 0.05 * np.arange(1, 401)
    var = walks.var(axis=0)
    slope, icpt = np.polyfit(t, var, 1)
    assert abs(slope - 0.1) < 0.01 and abs(icpt) < 0.05  # Var = sd_ref² t / t_ref
    assert np.corrcoef(t, var)[0, 1] > 0.99


def test_quantised_values_on_the_grid() -> None:
    spec = sn.NoiseSpec("quantised", 0.005, bits=8, seed=5)
    x = np.sin(np.linspace(0, 6, 500)) * 3.0
    rng_ = sn.channel_range(x)
    y = sn.apply_noise(spec, {"p_lift": x}, 0.1, 0.1, {"p_lift": rng_}).measured["p_lift"]
    step = rng_ / 2**8
    k = y / step
    assert np.allclose(k, np.round(k), atol=1e-9)
    assert len(np.unique(np.round(k))) > 50 and np.max(np.abs(y - x)) < step / 2 + 5 * 0.25 * 0.005 * rng_


@pytest.mark.parametrize(("h", "tau"), [(0.002, 0.05), (0.01, 0.3), (0.1, 0.2)])
def test_lowpass_lags_by_tau(h: float, tau: float) -> None:
    t = np.arange(0, 40, h)
    x = np.sin(2 * np.pi * 0.05 * t)  # slow: the filter's delay is ≈ τ at this frequency
    y = sn.lowpass(x, h, tau)
    assert y[0] == x[0]
    fine = np.arange(-1.0, 1.0, 0.001)
    late = t > 5 * tau + 2
    err = [np.sum((np.interp(t[late] - d, t, x) - y[late]) ** 2) for d in fine]
    lag = fine[int(np.argmin(err))]
    assert abs(lag - tau) < 0.02 * tau + 0.002
    ramp = sn.lowpass(t, h, tau)
    assert abs((t - ramp)[-1] - tau) < 1e-9  # a ramp lags by exactly τ


def test_noise_is_deterministic_per_seed() -> None:
    chans = ("F21", "p_lift")
    for fam in sn.FAMILIES:
        a = sn.draw_noise(np.random.default_rng([7, 1]), fam, chans)
        b = sn.draw_noise(np.random.default_rng([7, 1]), fam, chans)
        c = sn.draw_noise(np.random.default_rng([8, 1]), fam, chans)
        assert a == b and a != c
        lo, hi = sn.LEVEL_RANGE
        assert all(lo <= v <= hi for _, v in a.amplitudes)
        truth = {k: np.linspace(0, 1, 300) for k in chans}
        na = sn.apply_noise(a, truth, 0.1, 0.1, dict.fromkeys(chans, 1.0)).measured
        nb = sn.apply_noise(b, truth, 0.1, 0.1, dict.fromkeys(chans, 1.0)).measured
        nc = sn.apply_noise(a, truth, 0.1, 0.1, dict.fromkeys(chans, 1.0), sub_seed=1).measured
        assert all(np.array_equal(na[k], nb[k]) for k in chans)
        assert not np.array_equal(na["F21"], nc["F21"])


def test_case_draw() -> None:
    assert all(np.log10(hi / lo) >= MIN_DECADES for lo, hi, _ in RANGES.values())
    cases = make_cases(40, 3)
    assert [c.key() for c in cases] == [c.key() for c in make_cases(40, 3)]
    assert make_cases(5, 3)[4].key() == cases[4].key()  # prefix-stable
    assert make_cases(5, 4)[4].key() != cases[4].key()
    assert [c.kind for c in cases[:20]] == list(KIND_PATTERN)
    nulls = {c.noise.family for c in cases if c.kind == "null"}
    assert nulls == set(sn.FAMILIES)  # 12 nulls dealt over the five families in shuffled rounds
    counts = [sum(c.kind == "null" and c.noise.family == f for c in cases) for f in sn.FAMILIES]
    assert min(counts) >= 2
    assert any(c.meta["scale"] not in ("mini", "er12", "wa475") for c in cases)
    assert len({c.meta["soil"] for c in cases}) == 4
    only = make_case(2, 3, families=("ar1",), conditions=("200hz",))
    assert only.noise.family == "ar1" and only.condition == Condition("200hz", rate_hz=200.0)
    with pytest.raises(ValueError):
        make_case(0, 0, families=("pink",))


def test_parse_label() -> None:
    assert parse_label("coulomb_friction:lift_cylinder") == ("coulomb_friction", "lift_cylinder")
    assert parse_label("coulomb_friction[boom_hinge]") == ("coulomb_friction", "boom_hinge")
    assert parse_label("payload_mass_error") == ("payload_mass_error", None)


def test_csv_log_at_200hz_round_trips(tmp_path: Path) -> None:
    dt = 0.1
    time = dt * np.arange(1, 41)
    commands = np.stack([np.sin(time), np.cos(time), 0.5 * np.ones_like(time)], axis=1)
    names = ("time", "F21", "F31", "Pf_tilt", "Pf_lift", "x_b", "y_b", "m_b", "a1", "alpha1", "V1", "w1", "p_lift",
             "boom_angle", "travel_speed")
    signals = {k: 1e3 * (1 + i) * np.sin(time + i) for i, k in enumerate(names[1:])}
    log = resample(time, commands, signals, Condition("200hz", rate_hz=200.0), dt)
    assert np.allclose(np.diff(log.time), 0.005)
    assert np.allclose(np.interp(time, log.time, log.truth["F21"]), signals["F21"])  # the truth at control steps
    k = np.searchsorted(time, log.time[5:20])  # command k held over (t_{k-1}, t_k]
    assert np.array_equal(log.commands[5:20], commands[k])
    path = write_csv(tmp_path / "log.csv", log.time, log.commands, log.truth)
    header = path.read_text().splitlines()[0]
    assert "F21 [kN]" in header and "p_lift [bar]" in header and "x_b [mm]" in header and "time [ms]" in header
    assert LOG_UNITS["boom_angle"] == "deg" and "boom_angle [deg]" in header
    rec = import_recording(path)
    assert np.allclose(rec.data["time"], log.time, rtol=1e-9)
    for name in ("F21", "p_lift", "x_b", "boom_angle", "travel_speed", "m_b"):
        assert np.allclose(rec.data[name], log.truth[name], rtol=1e-8, atol=1e-9), name
    assert rec.units["p_lift"] == "Pa" and rec.units["F21"] == "N"
    assert np.allclose(rec.data["cmd_lift"], log.commands[:, 0])


def test_offset_condition_shifts_signals(tmp_path: Path) -> None:
    dt = 0.1
    time = dt * np.arange(1, 101)
    sig = {"x_b": np.sin(0.5 * time)}
    log = resample(time, np.zeros((100, 3)), sig, Condition("offset", offset_s=0.3), dt)
    inner = log.time > 1.0
    assert np.allclose(log.truth["x_b"][inner], np.sin(0.5 * (log.time[inner] - 0.3)), atol=1e-4)
    lead = resample(time, np.zeros((100, 3)), sig, Condition("offset", offset_s=-0.3), dt)
    assert len(lead.time) == 97  # the last rows, whose truth lies beyond the recording, are dropped


@pytest.mark.slow
def test_bench_smoke(tmp_path: Path) -> None:
    """Two cases end to end through the CLI (a null and a single effect; native and a field log), then a rerun that
    skips both."""
    from scaletwin.cli import main

    out = tmp_path / "bench.md"
    args = ["bench-discrepancy", "--cases", "2", "--seed", "0", "--out", str(out), "--conditions", "native,csv",
            "--budget", "60"]
    assert main(args) == 0
    text = out.read_text()
    assert "## Per noise family" in text and "## Per input condition" in text and "git " in text
    rows = [json.loads(x) for x in (tmp_path / "bench_cases.jsonl").read_text().splitlines()]
    cases = [r for r in rows if "key" in r]
    assert len(cases) == len(rows) == 2 and {r["kind"] for r in cases} == {"null", "single"}
    assert all(r["run"]["git_rev"] and r["run"]["cores"] and r["run"]["seeds"] == [0] for r in cases)
    assert all("error" in r or "named" in r for r in cases)
    csv_lines = [x for x in (tmp_path / "bench_cases.csv").read_text().splitlines() if not x.startswith("#")]
    assert len(csv_lines) == 3 and csv_lines[0].startswith("index,key,seed,kind,family,condition")
    assert main(args) == 0  # resumed: nothing left to run
    again = [json.loads(x) for x in (tmp_path / "bench_cases.jsonl").read_text().splitlines()]
    assert len(again) == 2


def test_a_failing_case_is_recorded_not_raised(monkeypatch: pytest.MonkeyPatch) -> None:
    from discrepancy.bench import run as bench_run
    from discrepancy.data.channels import RecordingError

    def refuse(*args: object, **kwargs: object) -> None:
        raise RecordingError("sampled every 0.002 s but the twin steps every 0.1 s")

    monkeypatch.setattr(bench_run, "simulate", refuse)
    case = make_case(2, 0, conditions=("500hz",))
    result = bench_run.run_case(case)
    assert result["error"].startswith("RecordingError: sampled every")
    assert result["key"] == case.key() and result["condition"] == "500hz" and result["kind"] == "double"
    from discrepancy.bench.scoring import csv_row, summary, table

    assert summary([result])["errors"] == 1 and "## Errors" in table([result])
    assert csv_row(result)["error"] == result["error"]


def test_start_check_counts_cleared_cases_per_kind() -> None:
    """The benchmark report counts, per case kind, the logs without seed whose whole-log start cleared every
    located window; nothing is said when no case was checked."""
    def case(kind: str, after: int | None) -> dict:
        return {"kind": kind, "start_check": None if after is None else {"located_after": after}}

    ran = [case("null", 0), case("null", 2), case("single", 0), case("single", None), case("ooc", 4)]
    line = " ".join(start_check_lines(ran))
    assert "null 1 of 2" in line and "single 1 of 1" in line and "ooc 0 of 1" in line and "double" not in line
    assert start_check_lines([case("null", None)]) == []
