"""Shared fixtures for the environment tests."""

from __future__ import annotations

import gymnasium as gym
import pytest

import scaletwin_envs
from scaletwin_envs.policies import ScriptedDigPolicy
from scaletwin_envs.rollout import Episode, run_episode


@pytest.fixture(scope="session")
def scripted_episode():
    """One scripted dig per (scale, soil, law), cached for the session, with both routes to the pin forces."""
    cache: dict[tuple, Episode] = {}

    def get(scale: float | str = "mini", soil: str = "gravel", law: str = "product_line", seed: int = 0) -> Episode:
        key = (scale, soil, law, seed)
        if key not in cache:
            env = gym.make(scaletwin_envs.ENV_ID, scale=scale, soil=soil, law=law, two_route_check=True)
            cache[key] = run_episode(env, ScriptedDigPolicy(), seed=seed)
            cache[key].env = env  # type: ignore[attr-defined]
        return cache[key]

    return get
