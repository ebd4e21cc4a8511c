"""Training tools: the scale/soil randomiser, the random policy, the tuned teacher and behaviour cloning."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3.common.env_checker import check_env
from stable_baselines3.common.policies import ActorCriticPolicy

import scaletwin_envs
from scaletwin_envs.policies import TUNED, RandomPolicy, ScriptedDigPolicy
from scaletwin_envs.policies.cloning import Transitions, discounted, fit
from scaletwin_envs.policies.domain import CompletionBonus, RandomizedDigEnv, ScaleSoilSampler
from scaletwin_envs.rollout import run_episode


def test_sampler_covers_the_range_log_uniformly():
    sampler, rng = ScaleSoilSampler(), np.random.default_rng(0)
    draws = [sampler.sample(rng) for _ in range(400)]
    scales = np.array([d["scale"] for d in draws])
    assert scales.min() >= 0.05 and scales.max() <= 3.0
    assert abs(np.median(np.log(scales)) - 0.5 * (np.log(0.05) + np.log(3.0))) < 0.3
    assert {d["soil"] for d in draws} == {"gravel", "sand", "sandy_loam", "clay_loam"}


def test_sampler_draws_presets_and_laws():
    sampler = ScaleSoilSampler(laws=("product_line", "froude"), presets=("mini", "wa475"), preset_probability=0.5)
    rng = np.random.default_rng(1)
    draws = [sampler.sample(rng) for _ in range(200)]
    presets = [d["scale"] for d in draws if isinstance(d["scale"], str)]
    assert set(presets) == {"mini", "wa475"} and 60 < len(presets) < 140
    assert {d["law"] for d in draws} == {"product_line", "froude"}


@pytest.mark.parametrize("kwargs", [{"scale_range": (0.01, 1.0)}, {"soils": ("mud",)}, {"soils": ()},
                                    {"laws": ("cubic",)}, {"presets": ("d11",), "preset_probability": 0.5},
                                    {"preset_probability": 0.5}])
def test_sampler_rejects_unsupported_ranges(kwargs):
    with pytest.raises(ValueError):
        ScaleSoilSampler(**kwargs)


def test_randomized_env_rebuilds_per_episode_and_is_reproducible():
    env = RandomizedDigEnv(env_kwargs={"two_route_check": False}, seed=0)
    check_env(env, skip_render_check=True)
    first = [env.reset(seed=5)[1]["scale"], *(env.reset()[1]["scale"] for _ in range(3))]
    again = [env.reset(seed=5)[1]["scale"], *(env.reset()[1]["scale"] for _ in range(3))]
    assert first == again and len(set(first)) == 4
    obs_a, _ = env.reset(seed=9)
    obs_b, _ = env.reset(seed=9)
    np.testing.assert_array_equal(obs_a, obs_b)
    assert env.unwrapped.loader.scale == pytest.approx(env.drawn["scale"])


def test_completion_bonus_pays_for_delivered_fill():
    env = CompletionBonus(gym.make(scaletwin_envs.ENV_ID, scale="mini", two_route_check=False), weight=0.5)
    episode = run_episode(env, ScriptedDigPolicy(**TUNED), seed=0)
    last = episode.infos[-1]["reward_terms"]
    assert last["completion"] == pytest.approx(0.5 * episode.kpis.fill_factor)
    assert all("completion" not in info["reward_terms"] for info in episode.infos[:-1])
    with pytest.raises(ValueError):
        CompletionBonus(env, weight=-1.0)


def test_random_policy_reseeds():
    p = RandomPolicy(seed=1)
    a = [p(None) for _ in range(3)]
    p.reseed(1)
    np.testing.assert_array_equal(a, [p(None) for _ in range(3)])
    assert np.all(np.abs(a) <= 1.0) and p.predict(None)[0].shape == (3,)


def test_tuned_teacher_fills_fuller_than_the_default_cycle():
    env = gym.make(scaletwin_envs.ENV_ID, scale="wa475", soil="gravel", two_route_check=False)
    default = run_episode(env, ScriptedDigPolicy(), seed=0).kpis
    tuned = run_episode(env, ScriptedDigPolicy(**TUNED), seed=0).kpis
    assert tuned.fill_factor > max(default.fill_factor, 0.85)
    assert tuned.specific_energy < default.specific_energy


def test_discounted_returns():
    np.testing.assert_allclose(discounted([1.0, 0.0, 2.0], 0.5), [1.5, 1.0, 2.0])


@pytest.mark.parametrize("target", ["actor", "critic"])
def test_fit_moves_only_its_head_and_lowers_the_loss(target: str):
    torch.manual_seed(0)
    env = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    policy = ActorCriticPolicy(env.observation_space, env.action_space, lambda _: 1e-3, net_arch=[16])
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(256, 19)).astype(np.float32)
    data = Transitions(obs, np.tanh(obs[:, :3]), obs[:, 0] ** 2, np.zeros(1))
    other = "value_net" if target == "actor" else "action_net"
    before = {k: v.clone() for k, v in policy.state_dict().items() if k.startswith(other)}
    losses = fit(policy, data, target, epochs=30, batch_size=64, lr=3e-3)
    assert losses[-1] < 0.5 * losses[0]
    for k, v in before.items():
        torch.testing.assert_close(policy.state_dict()[k], v)
    with pytest.raises(ValueError):
        fit(policy, data, "both", epochs=1)
