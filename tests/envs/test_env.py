"""WheelLoaderDig-v1 as a Gymnasium environment: API, determinism, bad input, blow-ups."""

from __future__ import annotations

import math

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import scaletwin_envs
from scaletwin_envs.envs.wheel_loader_dig import OBS_NAMES


@pytest.mark.parametrize("scale", ["mini", "er12", "wa475", 0.1, 0.5, 2.0])
def test_both_env_checkers_pass(scale: str | float) -> None:
    env = gym.make(scaletwin_envs.ENV_ID, scale=scale)
    gym_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env, warn=False)


BODY_PARENTS = {"frame": "world", "boom": "frame", "bucket": "boom", "payload": "bucket", "bell_crank": "boom",
                "link_b": "bell_crank", "lift_barrel": "frame", "lift_rod": "lift_barrel", "tilt_barrel": "frame",
                "tilt_rod": "tilt_barrel", "lift_supply": "world", "tilt_supply": "world"}  # supplies: the valves
SLIDES = {"drive", "lift_cylinder", "tilt_cylinder", "lift_supply", "tilt_supply"}
HINGES = {"boom_hinge", "bucket_hinge", "bell_crank_hinge", "link_b_hinge", "lift_barrel_hinge", "tilt_barrel_hinge"}


@pytest.mark.parametrize("scale", ["mini", "wa475"])
def test_make_registers_and_exposes_model_data(scale: str) -> None:
    """The registered id builds the Z-bar loader: its bodies, joints and sites, each body with the spec's mass."""
    env = gym.make("scaletwin_envs:WheelLoaderDig-v1", scale=scale, soil="sand")
    u, spec = env.unwrapped, scaletwin_envs.make_loader(scale)
    m = u.model
    assert u.loader == spec and u.soil == scaletwin_envs.make_soil("sand")
    parents = {m.body(i).name: m.body(int(m.body_parentid[i])).name for i in range(1, m.nbody)}
    assert parents == BODY_PARENTS
    joints = {m.joint(i).name: int(m.jnt_type[i]) for i in range(m.njnt)}
    assert joints == {**{j: int(mujoco.mjtJoint.mjJNT_SLIDE) for j in SLIDES},
                      **{j: int(mujoco.mjtJoint.mjJNT_HINGE) for j in HINGES}}
    sites = {m.site(i).name for i in range(m.nsite)}
    assert {"pin_O", "pin_21", "bucket_edge", "bucket_heel", "bucket_back_top"} <= sites
    masses = spec.masses
    expected = {"frame": masses.chassis, "boom": masses.boom, "bucket": masses.bucket, "bell_crank": masses.bell_crank,
                "link_b": masses.link_b, "lift_barrel": spec.lift.barrel_mass, "lift_rod": spec.lift.rod_mass,
                "tilt_barrel": spec.tilt.barrel_mass, "tilt_rod": spec.tilt.rod_mass}
    assert {b: float(m.body(b).mass[0]) for b in expected} == pytest.approx(expected, rel=1e-12)
    # empty payload: ~1e-9 bucket; each supply ~1e-9 of its slide's inertia (all its inertia is its armature)
    assert mujoco.mj_getTotalmass(m) == pytest.approx(spec.operating_mass, rel=1e-8)
    assert u.data.qpos.shape == (m.nq,) and m.nq == m.nv == len(SLIDES | HINGES)
    assert env.observation_space.shape == (len(OBS_NAMES),)


def _trajectory(seed: int, steps: int = 40) -> np.ndarray:
    env = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(123)
    out = [obs]
    for _ in range(steps):
        obs, *_ = env.step(rng.uniform(-1, 1, 3).astype(np.float32))
        out.append(obs)
    return np.array(out)


def test_same_seed_same_trajectory() -> None:
    a, b, c = _trajectory(7), _trajectory(7), _trajectory(8)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def _reset_state(env: gym.Env, seed: int) -> dict[str, np.ndarray | float]:
    """Start pose (boom, bucket hinge), full state, pile (toe relative to the edge, height, repose) and obs."""
    obs, _ = env.reset(seed=seed)
    u = env.unwrapped
    m, d, pile = u.model, u.data, u.pile
    edge_x = float(d.site("bucket_edge").xpos[0])
    rising = int(np.argmax(pile.initial > 0))  # first cell on the slope: h = (x - toe) tan(repose)
    return {"boom": float(d.qpos[m.joint("boom_hinge").qposadr[0]]),
            "bucket": float(d.qpos[m.joint("bucket_hinge").qposadr[0]]),
            "qpos": d.qpos.copy(), "qvel": d.qvel.copy(), "obs": obs, "pile_h": pile.initial.copy(),
            "toe": (float(pile.x[0]) - edge_x) / u.length, "height": float(pile.initial.max()) / u.length,
            "repose": math.atan2(float(pile.initial[rising]), float(pile.x[rising] - pile.x[0]))}


def test_seeded_reset_randomises_pile_and_pose() -> None:
    """No noise: every seed starts from the nominal state. Noise: pose and pile move within the documented bounds
    (boom +0..0.03 rad, bucket ±0.03 rad, toe ±0.05 L, height ±8 %, repose ±2°) and differ from seed to seed."""
    quiet = gym.make(scaletwin_envs.ENV_ID, scale="er12", reset_noise_scale=0.0)
    a, b = _reset_state(quiet, 1), _reset_state(quiet, 2)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert a["boom"] == 0.0 and a["bucket"] == 0.0 and not a["qvel"].any()
    assert a["toe"] == pytest.approx(0.5, abs=1e-9)  # pile_distance, boom lengths
    assert a["height"] == pytest.approx(0.7, rel=1e-9)  # pile_height, boom lengths
    assert a["repose"] == pytest.approx(scaletwin_envs.make_soil("gravel").repose_angle, abs=1e-9)

    env = gym.make(scaletwin_envs.ENV_ID, scale="er12")
    noisy = [_reset_state(env, seed) for seed in range(4)]
    for s in noisy:
        assert 0.0 <= s["boom"] <= 0.03 and -0.03 <= s["bucket"] <= 0.03
        assert s["toe"] == pytest.approx(0.5, abs=0.05 + 1e-9)
        assert s["height"] == pytest.approx(0.7, rel=0.08 + 1e-9)
        assert s["repose"] == pytest.approx(a["repose"], abs=math.radians(2.0) + 1e-9)
    for key in ("boom", "bucket", "toe", "height", "repose"):
        values = [s[key] for s in noisy]
        assert len(set(values)) == 4, key  # each seed draws its own
        assert max(abs(v - a[key]) for v in values) > 0.1 * {"boom": 0.03, "bucket": 0.03, "toe": 0.05,
                                                               "height": 0.056, "repose": math.radians(2)}[key], key
    np.testing.assert_array_equal(_reset_state(env, 2)["qpos"], noisy[2]["qpos"])  # and the same seed repeats


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"scale": 0}, "scale"), ({"scale": float("nan")}, "scale"), ({"scale": "tiny"}, "preset"),
     ({"soil": "mud"}, "soil"), ({"distortion": {"speed": 2}}, "distortion"), ({"pile_height": -1}, "pile_height"),
     ({"frame_skip": 0}, "frame_skip"), ({"render_mode": "video"}, "render_mode")],
)
def test_bad_kwargs_raise_value_error(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        gym.make(scaletwin_envs.ENV_ID, **kwargs)


@pytest.mark.parametrize("action", [np.zeros(2), np.zeros((1, 3)), np.array([0.0, np.nan, 0.0])])
def test_bad_actions_raise_value_error(action: np.ndarray) -> None:
    env = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.unwrapped.step(action)


def test_blow_up_truncates_with_sim_error_and_no_nan() -> None:
    env = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    obs, _ = env.reset(seed=0)
    env.unwrapped.model.opt.gravity[2] = np.nan  # a user's broken model: accelerations cannot be computed
    for _ in range(20):
        obs, reward, _, truncated, info = env.step(np.array([1.0, 1.0, 1.0], dtype=np.float32))
        assert np.all(np.isfinite(obs)) and np.isfinite(reward)
        if truncated:
            break
    assert truncated and info["sim_error"]


def test_reward_terms_sum_to_reward() -> None:
    env = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    env.reset(seed=0)
    for _ in range(5):
        _, reward, _, _, info = env.step(np.array([0.0, 0.5, 1.0], dtype=np.float32))
        assert reward == pytest.approx(sum(info["reward_terms"].values()))
        assert set(info["reward_terms"]) == {"fill", "time", "energy", "spill"}


def test_render_rgb_array_scales_camera_with_machine() -> None:
    pytest.importorskip("OpenGL")
    for scale in ("mini", "wa475"):
        env = gym.make(scaletwin_envs.ENV_ID, scale=scale, render_mode="rgb_array", width=160, height=120)
        env.reset(seed=0)
        try:
            frame = env.render()
        except Exception as exc:  # no GL on this machine: rendering is optional in CI
            pytest.skip(f"no OpenGL context: {exc}")
        assert frame.shape == (120, 160, 3)
        assert frame.std() > 5  # not a blank image
        env.close()


@pytest.mark.parametrize("scale", ["mini", "wa475", 0.05, 3.0])
def test_loops_are_closed_at_reset(scale: str | float) -> None:
    env = gym.make(scaletwin_envs.ENV_ID, scale=scale)
    for seed in range(3):
        env.reset(seed=seed)
        d = env.unwrapped.data
        for a, b in (("pin_21", "link_b_tip"), ("lift_boom_pin", "lift_rod_tip"), ("bell_crank_top", "tilt_rod_tip")):
            assert np.linalg.norm(d.site(a).xpos - d.site(b).xpos) < 1e-9 * env.unwrapped.length


def test_scale_accepts_a_loader_spec_and_distortions() -> None:
    spec = scaletwin_envs.make_loader(0.7, distortion={"pressure": 1.3})
    env = gym.make(scaletwin_envs.ENV_ID, scale=spec)
    assert env.unwrapped.loader is spec
    env = gym.make(scaletwin_envs.ENV_ID, scale=0.7, law="froude", distortion={"mass": 1.1})
    assert env.unwrapped.loader.operating_mass == pytest.approx(
        1.1 * scaletwin_envs.make_loader(0.7, law="froude").operating_mass)


def test_the_randomised_env_passes_both_env_checkers() -> None:
    """The suite's third env (a new machine size and soil at every reset) meets the same conventions; the checkers
    reset it several times, so several machines are built and checked."""
    env = gym.make(scaletwin_envs.RANDOM_ENV_ID)
    gym_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env, warn=False)
