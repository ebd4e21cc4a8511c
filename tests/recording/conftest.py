"""Shared fixtures: scripted mini-scale recordings, cached for the session (each takes ~0.2 s)."""

from __future__ import annotations

import os
from collections.abc import Callable

import gymnasium as gym
import pytest

import scaletwin_envs
from scaletwin_envs.policies import ScriptedDigPolicy
from scaletwin_envs.recording import Recording, record_episode

os.environ.setdefault("CI", "1")  # rerun CLI/SDK: no analytics banner in tests


@pytest.fixture(scope="session")
def recorded() -> Callable[..., Recording]:
    """``recorded(seed=0, **env_kwargs)``: a scripted mini dig (gym.make), recorded once per argument set."""
    cache: dict[tuple, Recording] = {}

    def get(seed: int = 0, **kwargs: object) -> Recording:
        key = (seed, tuple(sorted(kwargs.items())))
        if key not in cache:
            env = gym.make(scaletwin_envs.ENV_ID, **{"scale": "mini", **kwargs})
            cache[key] = record_episode(env, ScriptedDigPolicy(), seed=seed)
        return cache[key]

    return get
