"""Vector envs: gymnasium's async vector env and Stable-Baselines3's SubprocVecEnv, two worker processes each.

Each sub-env must follow its own seed exactly as a single env does (determinism per seed), the two sub-envs must
differ, and a sub-env whose episode ends is reset by the vector env (autoreset) without an error.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import scaletwin_envs

KWARGS = {"scale": "mini", "two_route_check": False}
ACTIONS = np.array([[0.2, 0.1, 1.0], [-0.3, 0.5, 0.8], [0.0, 0.0, 1.0], [0.6, -0.2, 0.4]], dtype=np.float32)


def _single(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Observations and rewards of one env reset with ``seed`` and stepped through ACTIONS."""
    env = gym.make(scaletwin_envs.ENV_ID, **KWARGS)
    obs, _ = env.reset(seed=seed)
    out, rewards = [obs], []
    for a in ACTIONS:
        obs, reward, *_ = env.step(a)
        out.append(obs)
        rewards.append(reward)
    return np.array(out), np.array(rewards)


def _gym_async(seed: int) -> tuple[np.ndarray, np.ndarray, list[dict]]:
    envs = gym.make_vec(scaletwin_envs.ENV_ID, num_envs=2, vectorization_mode="async", **KWARGS)
    try:
        obs, _ = envs.reset(seed=seed)  # sub-env i is seeded with seed + i
        out, rewards, infos = [obs], [], []
        for a in ACTIONS:
            obs, reward, _, _, info = envs.step(np.stack([a, a]))
            out.append(obs)
            rewards.append(reward)
            infos.append(info)
        return np.array(out), np.array(rewards), infos
    finally:
        envs.close()


def test_gym_async_vector_env_is_deterministic_per_seed() -> None:
    obs, rewards, infos = _gym_async(10)
    assert obs.shape == (len(ACTIONS) + 1, 2, len(scaletwin_envs.envs.wheel_loader_dig.OBS_NAMES))
    again, rewards_again, _ = _gym_async(10)
    np.testing.assert_array_equal(obs, again)
    np.testing.assert_array_equal(rewards, rewards_again)
    for i in range(2):  # each sub-env is the single env with its own seed, step for step
        single_obs, single_rewards = _single(10 + i)
        np.testing.assert_array_equal(obs[:, i], single_obs)
        np.testing.assert_allclose(rewards[:, i], single_rewards, rtol=1e-6)  # float32 in the vector buffer
    assert not np.array_equal(obs[0, 0], obs[0, 1])  # two seeds, two starts
    assert "fill_factor" in infos[-1] and infos[-1]["fill_factor"].shape == (2,)  # info dicts are batched


def _sb3_subproc(seed: int) -> np.ndarray:
    from stable_baselines3.common.vec_env import SubprocVecEnv

    envs = SubprocVecEnv([lambda: gym.make(scaletwin_envs.ENV_ID, **KWARGS) for _ in range(2)])
    try:
        envs.seed(seed)  # sub-env i: seed + i, used at the next reset
        out = [envs.reset()]
        for a in ACTIONS:
            obs, _, _, _ = envs.step(np.stack([a, a]))
            out.append(obs)
        return np.array(out)
    finally:
        envs.close()


def test_sb3_subproc_vec_env_is_deterministic_per_seed() -> None:
    pytest.importorskip("stable_baselines3")
    obs = _sb3_subproc(20)
    np.testing.assert_array_equal(obs, _sb3_subproc(20))
    for i in range(2):
        np.testing.assert_array_equal(obs[:, i], _single(20 + i)[0])
    assert not np.array_equal(obs[0, 0], obs[0, 1])


def test_sb3_subproc_vec_env_autoresets_at_the_registered_horizon() -> None:
    """A 3-step TimeLimit: SB3 marks the step done, keeps the final observation and starts the next episode."""
    from stable_baselines3.common.vec_env import SubprocVecEnv

    envs = SubprocVecEnv([lambda: gym.make(scaletwin_envs.ENV_ID, max_episode_steps=3, **KWARGS) for _ in range(2)])
    try:
        envs.seed(0)
        envs.reset()
        for _ in range(2):
            _, _, dones, _ = envs.step(np.tile(ACTIONS[0], (2, 1)))
            assert not dones.any()
        obs, _, dones, infos = envs.step(np.tile(ACTIONS[0], (2, 1)))
        assert dones.all()
        for i in range(2):
            assert infos[i]["TimeLimit.truncated"] is True
            assert not np.array_equal(infos[i]["terminal_observation"], obs[i])  # obs is already the new episode's
            assert obs[i][scaletwin_envs.envs.wheel_loader_dig.OBS_INDEX["time"]] == 0.0
    finally:
        envs.close()
