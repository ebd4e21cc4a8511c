"""The bucket's rack-back stop: where it lies (short of link B's dead centre by the margin), that the simulated
Z-bar stays on its assembly branch against it, and that the second route to the pin forces counts its moment."""

from __future__ import annotations

import math

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import scaletwin_envs
from scaletwin_envs.design_space import DesignSpace
from scaletwin_envs.physics.kinematics import (
    BUCKET_STOP_MARGIN,
    LinkageUnreachable,
    bucket_angle_for_tilt_length,
    bucket_stops,
    link_b_transmission,
    solve_pose,
)
from scaletwin_envs.policies import ScriptedDigPolicy
from scaletwin_envs.recording.recorder import record_episode
from scaletwin_envs.recording.sweep import make_policy
from scaletwin_envs.rollout import run_episode
from scaletwin_envs.specs import make_loader
from scaletwin_envs.specs.loader import LoaderSpec

PRESETS = ("er12", "mini", "wa475")


def _machines() -> list[tuple[str, LoaderSpec]]:
    line = DesignSpace().sample(6, seed=5)
    return [(p, make_loader(p)) for p in PRESETS] + [(m.name, m.spec) for m in line]


def _clearance(spec: LoaderSpec, bucket: float) -> float:
    """How far link B is from a dead centre with the bucket's lever at this bucket angle (rad), boom lowered."""
    gamma = link_b_transmission(solve_pose(spec.geometry, 0.0, bucket))
    return min(gamma, math.pi - gamma)


@pytest.mark.parametrize(("name", "spec"), _machines(), ids=lambda v: v if isinstance(v, str) else "")
def test_the_stop_lies_the_margin_short_of_the_dead_centre(name: str, spec: LoaderSpec) -> None:
    lo, hi = bucket_stops(spec.geometry)
    assert lo < 0.0 < hi <= math.pi
    assert _clearance(spec, hi) == pytest.approx(BUCKET_STOP_MARGIN, abs=1e-6)
    # every bucket angle between the reference pose and the stop keeps more than the margin
    assert all(_clearance(spec, b) > BUCKET_STOP_MARGIN for b in np.linspace(0.0, hi - 1e-3, 50))
    # past the stop the clearance keeps falling to the dead centre: the stop is the first crossing, not any
    beyond = [_clearance(spec, hi + d) for d in (0.01, 0.02)]
    assert beyond[0] < BUCKET_STOP_MARGIN and beyond[1] < beyond[0]
    # a wider margin stops the bucket earlier
    assert bucket_stops(spec.geometry, math.radians(20.0))[1] < hi


def test_bad_margin_and_a_reference_pose_at_the_dead_centre_are_refused() -> None:
    g = make_loader("er12").geometry
    with pytest.raises(ValueError, match="margin"):
        bucket_stops(g, -0.1)
    with pytest.raises(ValueError, match="margin"):
        bucket_stops(g, math.pi / 2)
    # the ER12's reference pose keeps 78° from a dead centre: a margin of 80° leaves no room
    with pytest.raises(ValueError, match="dead centre"):
        bucket_stops(g, math.radians(80.0))


def _joint(model: mujoco.MjModel, name: str) -> int:
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)


@pytest.mark.parametrize("scale", PRESETS)
def test_full_rack_back_at_a_raised_boom_stops_at_the_stop_and_both_routes_agree(scale: str) -> None:
    """Lift and tilt both at full speed: the bucket curls back at a rising boom until it meets its stop (before the
    stops the ER12's linkage reached 3° from its dead centre there). On the stop the bucket stays within 5 mrad of
    it, link B keeps the margin (less 0.5°), and the Newton–Euler route to F21 and the tilt force agrees with
    MuJoCo's constraint forces (without the stop's moment in route 2 they differ by 2.6–8 force scales)."""
    env = gym.make(scaletwin_envs.ENV_ID, scale=scale, two_route_check=True)
    env.reset(seed=0)
    model, data = env.unwrapped.model, env.unwrapped.data
    j = _joint(model, "bucket_hinge")
    stop, adr = float(model.jnt_range[j][1]), int(model.jnt_qposadr[j])
    spec = make_loader(scale)
    on_stop, worst_residual, deepest, closest = 0, 0.0, -np.inf, np.inf
    for _ in range(120):
        _, _, terminated, truncated, info = env.step(np.array([1.0, 1.0, 0.0]))
        assert info["sim_error"] is None
        bucket = float(data.qpos[adr])
        deepest = max(deepest, bucket)
        s = info["signals"]
        pose = solve_pose(spec.geometry, s["boom_angle"], s["bucket_pitch"] - s["boom_angle"])
        gamma = link_b_transmission(pose)
        closest = min(closest, gamma, math.pi - gamma)
        if bucket > stop - 2e-3:
            on_stop += 1
            worst_residual = max(worst_residual, s["residual_F21"], s["residual_Pf_tilt"])
        if terminated or truncated:
            break
    env.close()
    assert on_stop >= 20, "the rack-back never reached the stop: the test would prove nothing"
    assert deepest < stop + 5e-3
    assert closest > BUCKET_STOP_MARGIN - math.radians(0.5)
    assert worst_residual < 1e-2


@pytest.mark.parametrize("scale", PRESETS)
def test_the_scripted_dig_never_reaches_the_stop(scale: str) -> None:
    """The stop changes no recording of the presets' scripted dig (the paper's data and the zoo's): it stays
    clear of it by at least 0.05 rad (the mini comes closest: 0.095 rad)."""
    env = gym.make(scaletwin_envs.ENV_ID, scale=scale)
    model = env.unwrapped.model
    j = _joint(model, "bucket_hinge")
    stop, adr = float(model.jnt_range[j][1]), int(model.jnt_qposadr[j])
    highest = -np.inf
    policy = ScriptedDigPolicy()

    def watch(*_: object) -> None:
        nonlocal highest
        highest = max(highest, float(env.unwrapped.data.qpos[adr]))

    run_episode(env, policy, seed=0, on_step=watch)
    env.close()
    assert highest < stop - 0.05


def test_a_product_line_rack_back_that_flipped_the_z_bar_stays_on_its_branch() -> None:
    """Design seed 0 machine 14, a hold episode of the product-line data (policy seed 1000190, sandy loam): the
    lowered boom pressed the bucket into the ground and curled it past link B's dead centre, and the simulated
    Z-bar went over to its other branch (109 of 290 rows with a bucket pitch 0.3–1.9 rad from the one the
    cylinder lengths give). With the stop every row's pitch is within 0.15 rad of it (compliance under load)."""
    machine = DesignSpace().sample_one(0, 14)
    spec = machine.spec
    env = gym.make(scaletwin_envs.ENV_ID, scale=spec, soil="sandy_loam", pile_distance=0.5, pile_height=0.7,
                   max_episode_time=90.0)
    rec = record_episode(env, make_policy("scaling.data.holds:make_hold_policy", n_poses=3, seed=1000190), 1000190)
    env.close()
    d = rec.data
    assert len(d) > 200
    gaps = []
    for boom, pitch, ext in zip(d["boom_angle"], d["bucket_pitch"], d["tilt_extension"], strict=True):
        try:
            bucket = bucket_angle_for_tilt_length(spec.geometry, float(boom), spec.tilt.closed_length + float(ext))
        except LinkageUnreachable:  # link B near straight under load: no rigid pose at these lengths
            continue
        gaps.append(abs((pitch - boom - bucket + math.pi) % (2 * math.pi) - math.pi))
    assert len(gaps) > 0.9 * len(d)
    assert max(gaps) < 0.15


def test_a_start_past_the_stop_is_refused_with_the_stop_named() -> None:
    env = gym.make(scaletwin_envs.ENV_ID, scale="er12")
    stop = bucket_stops(make_loader("er12").geometry)[1]
    env.reset(seed=0, options={"boom_angle": 0.5, "bucket_angle": stop - 0.05})  # inside: accepted
    with pytest.raises(ValueError, match="past the bucket's stops"):
        env.reset(seed=0, options={"boom_angle": 0.5, "bucket_angle": stop + 0.05})
    env.close()
