"""WheelLoaderDig-v0 as a Gymnasium environment: API, determinism, bad input, blow-ups."""

from __future__ import annotations

import gymnasium as gym
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


def test_make_registers_and_exposes_model_data() -> None:
    env = gym.make("scaletwin_envs:WheelLoaderDig-v0", scale="mini", soil="sand")
    u = env.unwrapped
    for body in ("boom", "bell_crank", "link_b", "bucket", "payload"):
        assert u.model.body(body).id >= 0
    for site in ("pin_O", "pin_21"):
        assert u.model.site(site).id >= 0
    for joint in ("lift_cylinder", "tilt_cylinder"):
        assert u.model.joint(joint).type == 2  # mjJNT_SLIDE
    assert u.data.qpos.shape == (u.model.nq,)
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


def test_seeded_reset_randomises_pile_and_pose() -> None:
    env = gym.make(scaletwin_envs.ENV_ID, scale="er12")
    toes = set()
    for seed in range(4):
        env.reset(seed=seed)
        toes.add(round(float(env.unwrapped.pile.x[0]), 6))
    assert len(toes) == 4
    quiet = gym.make(scaletwin_envs.ENV_ID, scale="er12", reset_noise_scale=0.0)
    quiet.reset(seed=1)
    x1 = quiet.unwrapped.pile.x[0]
    quiet.reset(seed=2)
    assert quiet.unwrapped.pile.x[0] == x1


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
