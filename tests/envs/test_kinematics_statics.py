"""Linkage kinematics and statics, checked against MuJoCo by independent routes."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from scaletwin_envs.builder import build_model
from scaletwin_envs.physics.bucket import load_centroid
from scaletwin_envs.physics.kinematics import LinkageUnreachable, pose_from_cylinders, solve_pose
from scaletwin_envs.physics.statics import solve_static
from scaletwin_envs.runtime import qpos_for_pose, set_payload
from scaletwin_envs.signals import SignalReader
from scaletwin_envs.specs import make_loader

LOOPS = (("pin_21", "link_b_tip"), ("lift_boom_pin", "lift_rod_tip"), ("bell_crank_top", "tilt_rod_tip"))


@pytest.mark.parametrize("scale", ["mini", "er12", "wa475", 0.1, 2.0])
def test_inverse_kinematics_round_trip(scale: str | float) -> None:
    g = make_loader(scale).geometry
    for boom, bucket in [(0.0, 0.0), (0.4, 0.3), (0.9, -0.2), (1.1, 0.5)]:
        pose = solve_pose(g, boom, bucket)
        back = pose_from_cylinders(g, pose.lift_length, pose.tilt_length)
        assert back.boom == pytest.approx(boom, abs=1e-9)
        assert back.bucket == pytest.approx(bucket, abs=1e-9)


def test_cylinder_strokes_cover_the_dig_workspace() -> None:
    spec = make_loader("er12")
    for boom, pitch in [(0.0, -0.3), (0.0, 0.9), (0.5, 0.6), (0.6, 0.9), (1.1, 1.4)]:
        pose = solve_pose(spec.geometry, boom, pitch - boom)
        for cyl, length in ((spec.lift, pose.lift_length), (spec.tilt, pose.tilt_length)):
            assert cyl.closed_length - 1e-9 <= length <= cyl.closed_length + cyl.stroke + 1e-9
    with pytest.raises(LinkageUnreachable):
        pose_from_cylinders(spec.geometry, 10.0, 1.0)


@pytest.mark.parametrize("scale", ["mini", "er12", "wa475", 0.05, 3.0])
def test_loops_are_closed_in_any_assembled_pose(scale: str | float) -> None:
    spec = make_loader(scale)
    model = build_model(spec)
    data = mujoco.MjData(model)
    data.qpos[:] = qpos_for_pose(model, spec, solve_pose(spec.geometry, 0.6, 0.4))
    mujoco.mj_forward(model, data)
    for a, b in LOOPS:
        gap = np.linalg.norm(data.site(a).xpos - data.site(b).xpos)
        assert gap < 1e-9 * spec.characteristic_length


def _settle(spec, boom: float, bucket: float, load: float):
    model = build_model(spec)
    data = mujoco.MjData(model)
    data.qpos[:] = qpos_for_pose(model, spec, solve_pose(spec.geometry, boom, bucket))
    com = load_centroid(spec.geometry, 0.7) - np.asarray(spec.geometry.pin_O)
    set_payload(model, data, load, com, 0.1 * spec.characteristic_length)
    mujoco.mj_step(model, data, int(15.0 * spec.froude_time / model.opt.timestep))
    mujoco.mj_forward(model, data)
    mujoco.mj_rnePostConstraint(model, data)
    areas = {k: (getattr(spec, k).bore_area, getattr(spec, k).annulus_area) for k in ("lift", "tilt")}
    return model, data, SignalReader(model, areas, spec.weight).read(data, np.zeros(2)), com


@pytest.mark.parametrize(("scale", "load_kg"), [("mini", 0.5), ("mini", 4.0), ("er12", 900.0), ("wa475", 6000.0)])
def test_pin_forces_at_rest_match_the_analytical_statics(scale: str, load_kg: float) -> None:
    """MuJoCo's constraint forces vs a static solution from geometry and masses alone (no MuJoCo forces)."""
    spec = make_loader(scale)
    model, data, sig, com = _settle(spec, 0.5, 0.3, load_kg)
    assert sig["a1"] * spec.froude_time / 9.81 < 1e-3  # really at rest
    boom = data.qpos[model.joint("boom_hinge").qposadr[0]]
    bucket = data.qpos[model.joint("bucket_hinge").qposadr[0]]
    ref = solve_static(spec, solve_pose(spec.geometry, boom, bucket), payload_mass=load_kg, payload_com_local=com)
    assert sig["F21"] == pytest.approx(ref.F21, rel=2e-3)
    assert sig["F31"] == pytest.approx(ref.F31, rel=2e-3)
    assert sig["Pf_lift"] == pytest.approx(ref.Pf_lift, rel=2e-3)
    assert sig["Pf_tilt"] == pytest.approx(ref.Pf_tilt, rel=2e-3)
    assert sig["m_b"] == pytest.approx(spec.masses.bucket + load_kg, rel=1e-6)


def test_static_equilibrium_of_the_whole_bucket() -> None:
    """F21 + F31 + weight of bucket and load = 0 at rest (Newton on the combined body)."""
    spec = make_loader("er12")
    ref = solve_static(spec, solve_pose(spec.geometry, 0.2, 0.4), payload_mass=700.0)
    total = ref.F21_vec + ref.F31_vec + np.array([0.0, -(spec.masses.bucket + 700.0) * 9.81])
    assert np.linalg.norm(total) < 1e-6 * spec.weight


def test_load_moves_pin_forces_linearly() -> None:
    spec = make_loader("mini")
    f = [solve_static(spec, solve_pose(spec.geometry, 0.4, 0.3), payload_mass=m,
                      payload_com_local=np.array([0.03, 0.0])).F21_vec for m in (0.0, 1.0, 2.0)]
    np.testing.assert_allclose(f[2] - f[1], f[1] - f[0], rtol=1e-9)  # statics is linear in the load
    assert np.linalg.norm(f[1]) > np.linalg.norm(f[0])
