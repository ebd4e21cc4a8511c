"""Import of external recordings: ``name [unit]`` headers converted to SI; clear errors listing what is expected."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from scaletwin_envs.recording import Provenance, import_recording, replay
from scaletwin_envs.recording.importer import expected_headers, to_si
from scaletwin_envs.recording.schema import REQUIRED_IMPORT

#: column → (unit written in the file, factor: file value = SI value × factor)
RIG_UNITS = {
    "time": ("ms", 1e3), "F21": ("kN", 1e-3), "F31": ("kN", 1e-3), "Pf_lift": ("MPa·m²", 1e-6),
    "Pf_tilt": ("kN", 1e-3), "x_b": ("mm", 1e3), "y_b": ("mm", 1e3), "p_lift": ("bar", 1e-5),
    "boom_angle": ("deg", 180 / np.pi), "a1": ("m/s^2", 1.0), "alpha1": ("rad/s²", 1.0),
    "q_boom_hinge": ("deg", 180 / np.pi), "q_lift_cylinder": ("mm", 1e3), "qd_lift_cylinder": ("mm/s", 1e3),
    "m_b": ("g", 1e3), "hydraulic_work": ("kJ", 1e-3),
}


def rig_frame(rec, columns=None) -> pd.DataFrame:
    """The recording as a real machine's log: mixed units in the headers, phase without a unit."""
    out = {}
    for col in columns or rec.data.columns:
        unit, factor = RIG_UNITS.get(col, (rec.units[col], 1.0))
        if col == "phase":
            out["phase"] = rec.data[col].to_numpy()
        else:
            out[f"{col} [{unit}]"] = rec.data[col].to_numpy(dtype=float) * factor
    return pd.DataFrame(out)


def assert_same_si(imported, rec) -> None:
    assert set(imported.data.columns) == set(rec.data.columns)
    for col in rec.data.columns:
        assert imported.units[col] == rec.units[col], col
        if col == "phase":
            assert imported.data[col].tolist() == rec.data[col].tolist()
        else:
            np.testing.assert_allclose(imported.signal(col), rec.signal(col), rtol=1e-12, atol=0, err_msg=col)


def test_csv_with_kn_mpa_mm_equals_the_si_recording(recorded, tmp_path):
    rec = recorded()
    rig_frame(rec).to_csv(tmp_path / "rig.csv", index=False)
    imported = import_recording(tmp_path / "rig.csv")
    assert_same_si(imported, rec)
    assert imported.provenance.source == "import"
    assert imported.provenance.extra["import"]["file"] == "rig.csv"
    assert "F21 [kN]" in imported.provenance.extra["import"]["headers"]


def test_parquet_import_and_provenance_allow_replay(recorded, tmp_path):
    rec = recorded()
    rig_frame(rec).to_parquet(tmp_path / "rig.parquet")
    prov = Provenance(machine=rec.provenance.machine, soil=rec.provenance.soil, seed=0,
                      env_kwargs=rec.provenance.env_kwargs)
    imported = import_recording(tmp_path / "rig.parquet", provenance=prov)
    assert_same_si(imported, rec)
    twin = replay(imported)  # the imported commands drive the twin through the same episode
    np.testing.assert_allclose(twin.signal("F21"), rec.signal("F21"), rtol=1e-9)


def test_minimal_log_gets_steps_and_keeps_only_given_columns(recorded, tmp_path):
    rec = recorded()
    rig_frame(rec, REQUIRED_IMPORT).to_csv(tmp_path / "min.csv", index=False)
    imported = import_recording(tmp_path / "min.csv")
    assert list(imported.data.columns) == ["step", *REQUIRED_IMPORT]
    assert imported.data["step"].tolist() == list(range(1, len(rec) + 1))


def test_missing_columns_are_listed_with_expected_units(recorded, tmp_path):
    rig_frame(recorded(), ["time", "cmd_lift", "F21"]).to_csv(tmp_path / "bad.csv", index=False)
    with pytest.raises(ValueError) as err:
        import_recording(tmp_path / "bad.csv")
    msg = str(err.value)
    assert "missing required columns: cmd_tilt, cmd_drive, F31" in msg
    assert "required: time [s], cmd_lift [1]" in msg and "Pf_lift [N]" in msg


def test_required_columns_can_be_relaxed(recorded, tmp_path):
    """What a user needs decides what is required: the discrepancy tool needs time and the commands only."""
    rig_frame(recorded(), ["time", "cmd_lift", "cmd_tilt", "cmd_drive", "F21"]).to_csv(tmp_path / "few.csv",
                                                                                      index=False)
    with pytest.raises(ValueError, match="missing required columns: F31"):
        import_recording(tmp_path / "few.csv")
    imported = import_recording(tmp_path / "few.csv", required=("time", "cmd_lift", "cmd_tilt", "cmd_drive"))
    assert list(imported.data.columns) == ["step", "time", "cmd_lift", "cmd_tilt", "cmd_drive", "F21"]


@pytest.mark.parametrize("sep", [";", "\t"])
def test_data_logger_csv_dialects(recorded, tmp_path, sep: str):
    """Semicolon or tab delimiters, a byte-order mark, spaces after delimiters and a trailing delimiter."""
    rec = recorded()
    frame = rig_frame(rec, REQUIRED_IMPORT)
    text = frame.to_csv(index=False, sep=sep).replace(sep, sep + " ").replace("\n", sep + "\n")
    (tmp_path / "logger.csv").write_bytes(b"\xef\xbb\xbf" + text.encode())
    imported = import_recording(tmp_path / "logger.csv")
    assert list(imported.data.columns) == ["step", *REQUIRED_IMPORT]
    np.testing.assert_allclose(imported.signal("F21"), rec.signal("F21"), rtol=1e-9)


@pytest.mark.parametrize(("header", "expected"), [
    ("R_x [kPa]", "unit 'kPa' is not convertible to 'N'"),
    ("travel_speed [blorp]", "unit 'blorp' is not convertible to 'm/s'"),
    ("R_z", "has no unit: write it as 'R_z [N]'"),
    ("F21 [N]", "column 'F21' appears twice"),
    ("torque [kN*m]", "unknown column 'torque [kN*m]'"),
    ("R_x [10**10**10]", "the number 10 is not a unit"),  # pint would build a number of 10^10 digits: a hang
    ("R_x [N²²²²²²]", "superscript exponent ²²²²²² is not accepted"),
])
def test_bad_headers_give_clear_errors(recorded, tmp_path, header, expected):
    frame = rig_frame(recorded(), REQUIRED_IMPORT)
    frame[header] = 1.0
    frame.to_csv(tmp_path / "bad.csv", index=False)
    with pytest.raises(ValueError, match=r"cannot import bad\.csv") as err:
        import_recording(tmp_path / "bad.csv")
    assert expected in str(err.value)
    assert "expected headers 'name [unit]'" in str(err.value)


def test_unknown_columns_can_be_ignored(recorded, tmp_path):
    frame = rig_frame(recorded(), REQUIRED_IMPORT)
    frame["operator [1]"] = 1.0
    frame.to_csv(tmp_path / "extra.csv", index=False)
    assert "operator" not in import_recording(tmp_path / "extra.csv", ignore_unknown=True).data.columns


def test_own_parquet_reads_back_and_other_formats_fail(recorded, tmp_path):
    rec = recorded()
    assert import_recording(rec.to_parquet(tmp_path / "own.parquet")).equals(rec)
    (tmp_path / "x.txt").write_text("a")
    with pytest.raises(ValueError, match=r"use a \.csv or \.parquet"):
        import_recording(tmp_path / "x.txt")
    with pytest.raises(FileNotFoundError):
        import_recording(tmp_path / "nope.csv")


def test_to_si_and_expected_headers():
    np.testing.assert_allclose(to_si(np.array([2.0]), "MPa·m²", "N"), [2e6])
    np.testing.assert_allclose(to_si(np.array([90.0]), "deg", "rad"), [np.pi / 2])
    np.testing.assert_allclose(to_si(np.array([50.0]), "%", "1"), [0.5])
    with pytest.raises(ValueError):
        to_si(np.array([1.0]), "kg", "N")
    assert "optional:" in expected_headers() and "q_<joint> [rad or m]" in expected_headers()


@pytest.mark.parametrize("unit", ["kN/", "furlongs", "N*", ""])
def test_malformed_units_are_value_errors(unit: str) -> None:
    """pint asserts or fails on some malformed unit strings; the importer always answers with a ValueError."""
    with pytest.raises(ValueError):
        to_si(np.ones(2), unit, "N")
