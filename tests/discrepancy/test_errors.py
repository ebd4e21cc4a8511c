"""Corrupted or mismatched recordings give clear errors; small pieces of the statistics."""

from __future__ import annotations

import numpy as np
import pytest

from discrepancy import RecordingError, TwinSpec, diagnose, load_episode
from discrepancy.data.episode import from_recording, to_recording
from discrepancy.stats.locate import benjamini_hochberg, windows
from scaletwin_envs.specs import make_loader, make_soil


@pytest.fixture(scope="module")
def recording(planted):
    return to_recording(planted([]).noisy)


def test_round_trip_through_parquet(recording, tmp_path) -> None:
    path = recording.to_parquet(tmp_path / "real.parquet")
    ep = load_episode(path)
    assert len(ep) == len(recording) and ep.seed == recording.provenance.seed


def test_corrupted_file(tmp_path) -> None:
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(b"PAR1 this is not a parquet file")
    with pytest.raises(RecordingError, match="cannot read recording"):
        load_episode(bad)
    with pytest.raises(FileNotFoundError):
        load_episode(tmp_path / "missing.parquet")


@pytest.mark.parametrize(("edit", "message"), [
    (lambda df: df.assign(cmd_lift=np.where((df.index >= 5) & (df.index < 15), np.nan, df["cmd_lift"])),
     r"cmd_lift is missing from t = 0\.6 s"),
    (lambda df: df.assign(cmd_lift=np.where(df.index == 5, np.inf, df["cmd_lift"])), "infinite"),
    (lambda df: df.assign(cmd_drive=df["cmd_drive"] * 40.0), "normalised"),
    (lambda df: df.assign(time=df["time"].to_numpy()[::-1].copy()), "does not increase"),
    (lambda df: df.assign(time=df["time"] ** 1.5), "uniformly"),
    (lambda df: df.head(4), "at least"),
])
def test_malformed_recordings(recording, edit, message: str) -> None:
    rec = recording
    data = edit(rec.data.copy())
    units = {c: u for c, u in rec.units.items() if c in data.columns}
    with pytest.raises(RecordingError, match=message):
        from_recording(type(rec)(data, units, rec.provenance))


def test_single_missing_command_is_held_and_reported(recording) -> None:
    data = recording.data.assign(cmd_lift=np.where(recording.data.index == 5, np.nan, recording.data["cmd_lift"]))
    ep = from_recording(type(recording)(data, recording.units, recording.provenance))
    assert ep.commands[5, 0] == recording.data["cmd_lift"].iloc[4]
    assert [g[0] for g in ep.input_report.gaps] == ["cmd_lift"]


def test_csv_without_commands(recording, tmp_path) -> None:
    data = recording.data.drop(columns=["cmd_tilt"])
    data.columns = [c if c in ("phase", "step") else f"{c} [{recording.units[c]}]" for c in data.columns]
    path = tmp_path / "real.csv"
    data.to_csv(path, index=False)
    with pytest.raises(RecordingError, match="cmd_tilt"):
        load_episode(path)


def test_mismatched_twin(planted) -> None:
    real = planted([]).noisy
    with pytest.raises(RecordingError, match="steps every"):
        diagnose(real, TwinSpec(make_loader("mini"), make_soil("gravel"), {}, 11))
    with pytest.raises(ValueError, match="seed must be an integer"):
        TwinSpec.parse("er12:gravel:x", real)


def test_benjamini_hochberg_and_windows() -> None:
    p = np.array([0.001, 0.01, 0.02, 0.5])
    assert np.allclose(benjamini_hochberg(p), [0.004, 0.02, 0.02 * 4 / 3, 0.5])
    wins = windows(np.array(["a"] * 23 + ["b"] * 3, dtype=object), max_len=10)
    assert [(w.phase, w.size) for w in wins] == [("a", 8), ("a", 7), ("a", 8), ("b", 3)]
