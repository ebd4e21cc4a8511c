"""Parquet round trip: lossless table, units of every column, provenance, determinism, atomic writes."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

import scaletwin_envs
from scaletwin_envs.physics.kinematics import solve_pose
from scaletwin_envs.physics.mass_layout import cylinder_axis
from scaletwin_envs.policies import ScriptedDigPolicy
from scaletwin_envs.recording import SCHEMA_VERSION, Recording, read_recording, record_episode
from scaletwin_envs.recording.schema import COMMAND_COLUMNS, METADATA_KEY
from scaletwin_envs.signal_units import EQ10, EQ23, SIGNAL_UNITS
from scaletwin_envs.specs import LoaderSpec, SoilSpec, make_loader, make_soil


def test_round_trip_is_lossless(recorded, tmp_path):
    rec = recorded()
    back = read_recording(rec.to_parquet(tmp_path / "ep.parquet"))
    pd.testing.assert_frame_equal(back.data, rec.data, check_exact=True)
    assert back.units == rec.units
    assert back.provenance == rec.provenance
    assert back.schema_version == SCHEMA_VERSION
    assert back.equals(rec)


def test_one_row_per_step_with_all_columns(recorded):
    rec = recorded()
    data = rec.data
    assert data["step"].tolist() == list(range(1, len(rec) + 1))
    assert np.all(np.diff(data["time"]) > 0)
    for col in ("time", *COMMAND_COLUMNS, *SIGNAL_UNITS, "q_boom_hinge", "qd_lift_cylinder", "m_load", "phase"):
        assert col in data.columns, col
    assert not data[list(dict.fromkeys((*EQ10, *EQ23)))].isna().any().any()
    assert set(data["phase"]) <= {"approach", "penetrate", "curl", "lift", "pull_back", "idle", "error"}
    assert data["m_load"].iloc[-1] > 0


def test_joint_states_match_the_model_and_signals(recorded):
    """Recorded joints and signals against independent references: the rigid linkage and time integration.

    The closed-form kinematics (:func:`solve_pose`) assembles the linkage from the recorded boom and bucket angles;
    the cylinder extensions (pin-to-pin length - closed length) and the bell crank and link B angles must follow.
    MuJoCo closes the loops with soft equality constraints, so under the dig's loads the simulated linkage departs
    from the rigid one (mini, seed 0: up to 0.5 % of L in cylinder length and 0.025 rad in link B, 2x margin below).
    Every recorded velocity, integrated over the recorded times, gives its position's change (the velocities step
    with the valves, so the trapezoid rule is good to ~5 % of the range; a wrong joint, sign or unit is far off).
    """
    rec = recorded()
    data = rec.data
    spec = rec.provenance.machine_spec()
    length = spec.characteristic_length
    poses = [solve_pose(spec.geometry, boom, bucket) for boom, bucket in zip(data["q_boom_hinge"],
                                                                              data["q_bucket_hinge"], strict=True)]
    # bucket pitch from the bucket body's rotation matrix = boom + bucket hinge angles
    np.testing.assert_allclose(data["bucket_pitch"], [p.bucket_pitch for p in poses], rtol=0, atol=1e-9)
    np.testing.assert_allclose(data["boom_angle"], [p.boom for p in poses], rtol=0, atol=1e-12)
    for cyl, lengths in (("lift", [p.lift_length for p in poses]), ("tilt", [p.tilt_length for p in poses])):
        closed = getattr(spec, cyl).closed_length
        np.testing.assert_allclose(data[f"{cyl}_extension"], np.array(lengths) - closed, rtol=0, atol=0.01 * length)
        _, ref = cylinder_axis(spec, cyl)  # slide joint zero = pin-to-pin length in the reference pose
        np.testing.assert_allclose(data[f"q_{cyl}_cylinder"] + ref, lengths, rtol=0, atol=0.01 * length)
    for joint, attr in (("bell_crank_hinge", "bell_crank"), ("link_b_hinge", "link_b"),
                        ("lift_barrel_hinge", "lift_angle"), ("tilt_barrel_hinge", "tilt_angle")):
        np.testing.assert_allclose(data[f"q_{joint}"], [getattr(p, attr) for p in poses], rtol=0, atol=0.05,
                                   err_msg=joint)
    t = data["time"].to_numpy()
    for position, velocity in (("q_drive", "travel_speed"), ("q_boom_hinge", "qd_boom_hinge"),
                               ("q_bucket_hinge", "qd_bucket_hinge"), ("lift_extension", "lift_speed"),
                               ("tilt_extension", "tilt_speed"), ("q_bell_crank_hinge", "qd_bell_crank_hinge")):
        q, v = data[position].to_numpy(), data[velocity].to_numpy()
        travelled = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
        assert np.ptp(q) > 0, position  # it moved
        np.testing.assert_allclose(q - q[0], travelled, rtol=0, atol=0.1 * np.ptp(q), err_msg=velocity)


def test_units_for_every_column(recorded):
    rec = recorded()
    assert list(rec.units) == list(rec.data.columns)
    assert rec.units["F21"] == "N" and rec.units["x_b"] == "m" and rec.units["time"] == "s"
    assert rec.units["q_boom_hinge"] == "rad" and rec.units["q_lift_cylinder"] == "m"
    assert rec.units["qd_drive"] == "m/s" and rec.units["cmd_lift"] == "1"
    assert all(rec.units[k] == v for k, v in SIGNAL_UNITS.items())


def test_provenance_rebuilds_machine_and_soil(recorded):
    p = recorded().provenance
    assert p.machine_spec() == make_loader("mini")
    assert p.soil_spec() == make_soil("gravel")
    assert p.seed == 0 and p.env_id == scaletwin_envs.ENV_ID
    assert p.package_version == scaletwin_envs.__version__ and p.mujoco_version
    assert p.timestep > 0 and p.frame_skip >= 1 and p.control_dt == pytest.approx(p.timestep * p.frame_skip)
    assert "ScriptedDigPolicy(" in p.policy and len(p.model_sha256) == 64
    assert p.env_kwargs["pile_distance"] == 0.5 and "scale" not in p.env_kwargs


def test_metadata_is_plain_json_in_the_file(recorded, tmp_path):
    path = recorded().to_parquet(tmp_path / "ep.parquet")
    meta = json.loads(pq.read_schema(path).metadata[METADATA_KEY])
    assert meta["schema_version"] == SCHEMA_VERSION
    assert meta["units"]["Pf_lift"] == "N"
    assert LoaderSpec.from_dict(meta["provenance"]["machine"]) == make_loader("mini")
    assert SoilSpec(**meta["provenance"]["soil"]).name == "gravel"


def test_same_seed_same_recording_and_bytes(recorded, tmp_path):
    env = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    again = record_episode(env, ScriptedDigPolicy(), seed=0)
    assert again.equals(recorded())
    a, b = recorded().to_parquet(tmp_path / "a.parquet"), again.to_parquet(tmp_path / "b.parquet")
    assert a.read_bytes() == b.read_bytes()
    other = record_episode(env, ScriptedDigPolicy(), seed=1)
    assert not other.data.equals(again.data)


def test_atomic_write_leaves_no_temporary_and_keeps_old_file_on_error(recorded, tmp_path):
    rec = recorded()
    path = rec.to_parquet(tmp_path / "ep.parquet")
    before = path.read_bytes()
    broken = Recording(rec.data.assign(F21=[object()] * len(rec)), rec.units, rec.provenance)
    with pytest.raises(Exception):  # noqa: B017 - pyarrow's error type for an unconvertible object column
        broken.to_parquet(path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["ep.parquet"]


def test_rejects_foreign_and_future_files(recorded, tmp_path):
    pd.DataFrame({"a": [1.0]}).to_parquet(tmp_path / "foreign.parquet")
    with pytest.raises(ValueError, match="not a scaletwin recording"):
        read_recording(tmp_path / "foreign.parquet")
    table = recorded().to_arrow()
    meta = json.loads(table.schema.metadata[METADATA_KEY])
    meta["schema_version"] = SCHEMA_VERSION + 1
    pq.write_table(table.replace_schema_metadata({METADATA_KEY: json.dumps(meta)}), tmp_path / "future.parquet")
    with pytest.raises(ValueError, match="schema version"):
        read_recording(tmp_path / "future.parquet")
    with pytest.raises(FileNotFoundError):
        read_recording(tmp_path / "missing.parquet")


def test_recording_validates_units(recorded):
    rec = recorded()
    units = dict(rec.units)
    del units["F21"]
    with pytest.raises(ValueError, match="columns without a unit \\['F21'\\]"):
        Recording(rec.data, units, rec.provenance)
