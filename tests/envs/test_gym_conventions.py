"""Gymnasium conventions of WheelLoaderDig-v1: horizon, info schema, finished episodes, rendering without a display,
reset options, the randomised-scale env, out-of-range actions and ``law`` with fixed machines."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import TimeLimit

import scaletwin_envs
from scaletwin_envs.envs.loader_base import EpisodeFinishedError, display_available
from scaletwin_envs.envs.wheel_loader_dig import INFO_KEYS, REWARD_TERMS, WheelLoaderDigEnv, horizon_steps
from scaletwin_envs.gl import offscreen_gl
from scaletwin_envs.policies.domain import RandomizedDigEnv

HOLD = np.zeros(3, dtype=np.float32)


# -- horizon -----------------------------------------------------------------------------------------------------
def test_registered_horizon_is_the_envs_own_truncation() -> None:
    """spec.max_episode_steps is the step at which the env truncates itself (60 Froude times), at every scale."""
    for env_id in (scaletwin_envs.ENV_ID, scaletwin_envs.RANDOM_ENV_ID):
        assert gym.spec(env_id).max_episode_steps == scaletwin_envs.MAX_EPISODE_STEPS == horizon_steps() == 290
    env = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    assert env.spec.max_episode_steps == 290
    assert isinstance(env, TimeLimit)
    for scale, law in (("er12", "product_line"), ("wa475", "product_line"), (0.05, "froude"), (3.0, "product_line")):
        u = gym.make(scaletwin_envs.ENV_ID, scale=scale, law=law).unwrapped
        assert u.horizon == 290, scale
    assert horizon_steps(90.0) == 435 and horizon_steps(60.0, frame_skip=50) == 580
    # without the TimeLimit wrapper, the env's own time limit truncates at exactly that step, not one earlier
    raw = WheelLoaderDigEnv(scale="mini", two_route_check=False)
    raw.reset(seed=0)
    for step in range(1, 291):
        _, _, terminated, truncated, info = raw.step(HOLD)
        assert not terminated
        assert truncated == (step == 290), step
    assert info["time"] == pytest.approx(290 * raw.dt) and info["time"] >= 60 * raw.loader.froude_time


# -- info schema and sim errors --------------------------------------------------------------------------------
def _scalar_values(info: dict) -> list[float]:
    out = [v for k, v in info.items() if isinstance(v, int | float) and not isinstance(v, bool)]
    return out + list(info["signals"].values()) + list(info["reward_terms"].values())


def test_sim_error_step_keeps_the_info_schema_and_blocks_further_steps() -> None:
    normal = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    normal.reset(seed=0)
    _, _, _, _, ok = normal.step(np.array([0.3, 0.2, 1.0], dtype=np.float32))
    assert tuple(ok) == INFO_KEYS and ok["sim_error"] is None and ok["action_clipped"] is False
    assert set(ok["reward_terms"]) == set(REWARD_TERMS)

    env = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    env.reset(seed=0)
    u = env.unwrapped
    for _ in range(3):  # a few good steps: load some soil so the reported load is not trivially zero
        env.step(np.array([0.3, 0.2, 1.0], dtype=np.float32))
    good = dict(u.signals)
    u.model.opt.gravity[2] = np.nan  # a user's broken model: accelerations cannot be computed
    obs, reward, terminated, truncated, info = env.step(np.array([1.0, 1.0, 1.0], dtype=np.float32))
    assert truncated and not terminated and reward == 0.0
    assert isinstance(info["sim_error"], str) and info["sim_error"]
    assert tuple(info) == INFO_KEYS  # the same keys as every step: info["fill_factor"] in a callback works
    assert set(info["signals"]) == set(ok["signals"]) and set(info["reward_terms"]) == set(REWARD_TERMS)
    assert info["signals"] == good  # the last good step's signals, not a diverged state
    assert info["phase"] == "error" and info["success"] is False
    assert all(v == 0.0 for v in info["reward_terms"].values())
    assert all(math.isfinite(v) for v in _scalar_values(info)) and np.all(np.isfinite(obs))

    with pytest.raises(EpisodeFinishedError, match="reset"):
        env.step(HOLD)  # MuJoCo reset the diverged state: carrying on silently would be wrong
    assert issubclass(EpisodeFinishedError, RuntimeError)
    u.model.opt.gravity[2] = -9.81
    env.reset(seed=0)
    _, _, _, truncated, info = env.step(HOLD)  # a reset clears it
    assert info["sim_error"] is None and not truncated


# -- rendering without a display ---------------------------------------------------------------------------------
@pytest.mark.parametrize("environ", [{"MUJOCO_GL": "egl"}, {"MUJOCO_GL": "osmesa", "DISPLAY": ":0"},
                                     {"MUJOCO_GL": "egl", "WAYLAND_DISPLAY": "wayland-0"}])
def test_human_rendering_without_a_display_is_a_clear_error(monkeypatch, environ: dict[str, str]) -> None:
    monkeypatch.setattr(sys, "platform", "linux")
    for var in ("DISPLAY", "WAYLAND_DISPLAY", "MUJOCO_GL"):
        monkeypatch.delenv(var, raising=False)
    for k, v in environ.items():
        monkeypatch.setenv(k, v)
    assert not display_available()
    with pytest.raises(ValueError, match="render_mode='human' needs a display"):
        gym.make(scaletwin_envs.ENV_ID, scale="mini", render_mode="human")
    env = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    assert env.unwrapped.metadata["render_modes"] == ["rgb_array", "depth_array"]  # what can work here
    assert "human" in type(env.unwrapped).metadata["render_modes"]


def test_display_detection(monkeypatch) -> None:
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setenv("DISPLAY", ":1")
    assert display_available()
    monkeypatch.delenv("DISPLAY")
    monkeypatch.setenv("WAYLAND_DISPLAY", "wayland-0")
    assert display_available()
    monkeypatch.setenv("MUJOCO_GL", "EGL")
    assert not display_available()


CHECK_ENV = """
import gymnasium as gym
from gymnasium.utils.env_checker import check_env
import scaletwin_envs
check_env(gym.make(scaletwin_envs.ENV_ID, scale="mini").unwrapped)
print("CHECKED")
"""


def test_check_env_with_default_arguments_survives_a_headless_machine() -> None:
    """gymnasium's check_env with its defaults renders every declared mode: without a display it used to reach the
    GL library's abort (SIGABRT, the interpreter gone). It runs in a child process so a regression fails the test."""
    environ = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "MUJOCO_GL")}
    result = subprocess.run([sys.executable, "-c", CHECK_ENV], capture_output=True, text=True, env=environ,
                            timeout=300)
    assert result.returncode >= 0, f"killed by signal {-result.returncode}: {result.stderr[-2000:]}"
    if result.returncode != 0:
        env = gym.make(scaletwin_envs.ENV_ID, scale="mini", render_mode="rgb_array", width=32, height=24)
        env.reset(seed=0)
        try:
            env.render()
        except Exception as exc:  # no off-screen GL on this machine: check_env may fail in a Python exception only
            assert "Traceback" in result.stderr
            pytest.skip(f"no off-screen OpenGL: {exc}")
    assert result.returncode == 0 and "CHECKED" in result.stdout, result.stderr[-3000:]


# -- reset options -----------------------------------------------------------------------------------------------
def _start(env: gym.Env, seed: int, options: dict | None = None) -> dict[str, float]:
    env.reset(seed=seed, options=options)
    u = env.unwrapped
    m, d, pile = u.model, u.data, u.pile
    rising = int(np.argmax(pile.initial > 0))
    return {"boom_angle": float(d.qpos[m.joint("boom_hinge").qposadr[0]]),
            "bucket_angle": float(d.qpos[m.joint("bucket_hinge").qposadr[0]]),
            "pile_distance": (float(pile.x[0]) - float(d.site("bucket_edge").xpos[0])) / u.length,
            "pile_height": float(pile.initial.max()) / u.length,
            "repose_angle": math.atan2(float(pile.initial[rising]), float(pile.x[rising] - pile.x[0]))}


def test_reset_options_set_the_start_exactly_and_leave_the_other_draws_alone() -> None:
    env = gym.make(scaletwin_envs.ENV_ID, scale="er12", reset_noise_scale=1.0)
    plain = _start(env, 3)
    options = {"boom_angle": 0.2, "bucket_angle": -0.1, "pile_distance": 0.8, "pile_height": 0.5,
               "repose_angle": math.radians(30.0)}
    for key, value in options.items():
        given = _start(env, 3, {key: value})
        assert given[key] == pytest.approx(value, abs=2e-3 if key == "repose_angle" else 1e-9), key
        assert abs(given[key] - plain[key]) > 1e-3, key  # the option changed something
        for other in options.keys() - {key}:  # the same seed draws the same for what was not given
            if key in ("boom_angle", "bucket_angle") and other == "pile_distance":
                continue  # the toe is placed from the edge, which the pose moves: checked relative to the edge above
            assert given[other] == pytest.approx(plain[other], abs=1e-12), (key, other)
    everything = _start(env, 4, options)
    for key, value in options.items():
        assert everything[key] == pytest.approx(value, abs=2e-3 if key == "repose_angle" else 1e-9), key
    assert _start(env, 3) == plain  # options hold for one episode only


@pytest.mark.parametrize(("options", "match"), [
    ({"pile_x": 1.0}, "unknown reset option"), ({"pile_height": -0.2}, "pile_height"),
    ({"pile_distance": float("nan")}, "finite"), ({"repose_angle": 2.0}, "repose_angle"),
    ({"boom_angle": 3.0}, "boom_angle"), ({"bucket_angle": "0.1"}, "finite"), ({"pile_height": True}, "finite"),
])
def test_bad_reset_options_raise_value_error(options: dict, match: str) -> None:
    env = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    with pytest.raises(ValueError, match=match):
        env.reset(seed=0, options=options)
    with pytest.raises(ValueError, match="dict"):
        env.reset(seed=0, options=[("pile_height", 0.5)])  # type: ignore[arg-type]


# -- the randomised env ------------------------------------------------------------------------------------------
def test_randomised_env_is_registered_with_kwargs_through_make() -> None:
    env = gym.make(scaletwin_envs.RANDOM_ENV_ID, scale_range=(0.2, 0.4), soils=("sand", "clay_loam"),
                   two_route_check=False, pile_height=0.6)
    assert env.spec.max_episode_steps == 290 and isinstance(env.unwrapped, WheelLoaderDigEnv)
    scales, soils = [], []
    for seed in range(4):
        obs, info = env.reset(seed=seed)
        u = env.unwrapped
        assert 0.2 <= u.loader.scale <= 0.4 and u.loader.scale == pytest.approx(info["scale"])
        assert u.soil.name == info["soil"] and u.soil.name in ("sand", "clay_loam")
        assert u.pile_height == 0.6 and u.two_route_check is False
        scales.append(u.loader.scale)
        soils.append(u.soil.name)
        again, _ = env.reset(seed=seed)
        np.testing.assert_array_equal(obs, again)
        assert env.unwrapped.loader.scale == scales[-1]
    assert len(set(scales)) == 4
    _, _, _, _, info = env.step(HOLD)
    assert tuple(info) == INFO_KEYS


def test_randomised_env_builds_presets_whatever_law_was_drawn() -> None:
    """A drawn law applies to drawn length ratios only; presets with a drawn 'froude' used to be ignored silently,
    the plain env now rejects that combination, so the randomised env must not pass it on."""
    env = gym.make(scaletwin_envs.RANDOM_ENV_ID, laws=("froude",), presets=("mini", "wa475"), preset_probability=1.0,
                   two_route_check=False)
    for seed in range(3):
        _, info = env.reset(seed=seed)
        assert info["scale"] in ("mini", "wa475") and env.unwrapped.loader == scaletwin_envs.make_loader(info["scale"])


@pytest.mark.parametrize(("kwargs", "match"), [({"scale": "mini"}, "drawn every episode"),
                                               ({"env_kwargs": {"soil": "sand"}}, "drawn every episode"),
                                               ({"soils": ("mud",)}, "soils"),
                                               ({"scale_range": (0.01, 1.0)}, "scale_range")])
def test_randomised_env_rejects_fixed_draws_and_bad_ranges(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        gym.make(scaletwin_envs.RANDOM_ENV_ID, **kwargs)


def test_randomised_env_honours_reset_options() -> None:
    env = RandomizedDigEnv(env_kwargs={"two_route_check": False}, seed=0)
    assert _start(env, 1, {"pile_height": 0.4})["pile_height"] == pytest.approx(0.4)


# -- actions and law ---------------------------------------------------------------------------------------------
def test_out_of_range_actions_are_clipped_and_reported() -> None:
    """As in gymnasium's MuJoCo v5 envs, [5, -3, 1.5] acts as [1, -1, 1]; info["action_clipped"] says so."""
    runs = {}
    for name, action in (("inside", [1.0, -1.0, 1.0]), ("outside", [5.0, -3.0, 1.5])):
        env = gym.make(scaletwin_envs.ENV_ID, scale="mini")
        env.reset(seed=1)
        out = [env.step(np.array(action, dtype=np.float32)) for _ in range(4)]
        runs[name] = out
    for (obs_a, r_a, *_, info_a), (obs_b, r_b, *_, info_b) in zip(runs["inside"], runs["outside"], strict=True):
        np.testing.assert_array_equal(obs_a, obs_b)
        assert r_a == r_b and info_a["signals"] == info_b["signals"]
        assert info_a["action_clipped"] is False and info_b["action_clipped"] is True
    assert runs["inside"][-1][0][scaletwin_envs.envs.wheel_loader_dig.OBS_INDEX["advance"]] > 0  # it drove


def test_law_with_a_fixed_machine_is_rejected() -> None:
    spec = scaletwin_envs.make_loader(0.5)
    for scale in ("mini", spec):
        with pytest.raises(ValueError, match="float scales only"):
            gym.make(scaletwin_envs.ENV_ID, scale=scale, law="froude")
        assert gym.make(scaletwin_envs.ENV_ID, scale=scale, law="product_line").unwrapped.loader.name  # the default
    froude = gym.make(scaletwin_envs.ENV_ID, scale=0.5, law="froude").unwrapped.loader
    assert froude.operating_mass != spec.operating_mass  # and with a length ratio the law is used


def test_the_offscreen_back_end_is_one_whose_library_is_there() -> None:
    """Without a display the package names an off-screen GL back end for MuJoCo only where its library exists:
    MuJoCo 4 loads it at import, so ``MUJOCO_GL=egl`` on a machine without libEGL made ``import mujoco`` fail
    (seen on a bare GPU container). EGL first, then OSMesa, else none (MuJoCo's default)."""
    assert offscreen_gl(lambda name: f"lib{name}.so.1") == "egl"
    assert offscreen_gl(lambda name: "libOSMesa.so.8" if name == "OSMesa" else None) == "osmesa"
    assert offscreen_gl(lambda name: None) is None
    environ = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "MUJOCO_GL")}
    code = "import os, scaletwin_envs; print(os.environ.get('MUJOCO_GL'))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environ, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == str(offscreen_gl())


def test_the_old_version_is_refused_with_a_pointer_to_the_new() -> None:
    """v1 changed the dynamics (servo, soil refresh): v0 is not registered, and gymnasium says which version is."""
    with pytest.raises(gym.error.DeprecatedEnv, match="WheelLoaderDig-v1"):
        gym.make("WheelLoaderDig-v0")
    assert scaletwin_envs.ENV_ID == "WheelLoaderDig-v1"
