"""The shipped learned policy fills the bucket at the miniature and at the WA475 (gravel, deterministic)."""

from __future__ import annotations

import gymnasium as gym
import pytest

import scaletwin_envs
import zoo
from scaletwin_envs.recording.recorder import record_episode
from scaletwin_envs.rollout import run_episode

FILL_THRESHOLD = 0.85


@pytest.fixture(scope="module")
def learned() -> zoo.ZooPolicy:
    return zoo.load("bucketfill-ppo")


@pytest.mark.parametrize("scale", ["mini", "wa475"])
def test_two_episodes_reach_the_fill_threshold(learned: zoo.ZooPolicy, scale: str):
    env = gym.make(scaletwin_envs.ENV_ID, scale=scale, soil="gravel", two_route_check=False)
    for seed in (0, 1):
        kpis = run_episode(env, learned, seed=seed).kpis
        assert kpis.sim_error is None
        assert kpis.fill_factor >= FILL_THRESHOLD, (scale, seed, kpis)
        assert kpis.success


def test_dataset_recorder_runs_the_learned_cycle(learned: zoo.ZooPolicy):
    env = gym.make(scaletwin_envs.ENV_ID, scale="er12", soil="gravel")
    recording = record_episode(env, learned, seed=0, policy_name="zoo:bucketfill-ppo")
    assert len(recording) > 10
