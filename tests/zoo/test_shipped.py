"""The shipped policy checkpoint: registered, hashes verified, rebuilt as an SB3 policy without pickle."""

from __future__ import annotations

import json

import numpy as np
import pytest
from stable_baselines3.common.policies import ActorCriticPolicy

import scaletwin_envs
import zoo
from scaletwin_envs.envs.wheel_loader_dig import OBS_NAMES
from zoo.checkpoint import verify_files
from zoo.registry import read_registry

SHIPPED = "bucketfill-ppo"
CARD_KEYS = ("kind", "algorithm", "env_id", "env_kwargs", "policy_kwargs", "observation_space", "action_space",
             "versions", "training", "metrics", "seed", "files")


def test_registered_and_listed():
    assert SHIPPED in zoo.list()
    assert SHIPPED in zoo.list(kind="policy")
    assert SHIPPED not in zoo.list(kind="scaling-model")


def test_card_has_every_field_and_pins_every_file():
    card = zoo.card(SHIPPED)
    for key in CARD_KEYS:
        assert key in card, key
    assert card["kind"] == "policy" and card["algorithm"] == "PPO"
    # trained on WheelLoaderDig-v0, not retrained for v1 (the same observation and action spaces; its KPIs on v1
    # are in benchmarks/results/policy_kpis.md): the card names the env it was trained on
    assert card["env_id"] == "WheelLoaderDig-v0" and scaletwin_envs.ENV_ID == "WheelLoaderDig-v1"
    assert card["observation_space"]["shape"] == [len(OBS_NAMES)]
    assert card["observation_space"]["names"] == list(OBS_NAMES)
    assert set(card["files"]) == {"weights.safetensors", "training.rrd"}
    directory, pinned = zoo.resolve(SHIPPED)
    assert pinned == read_registry()[SHIPPED]["card_sha256"] == zoo.sha256_file(directory / "card.json")
    verify_files(directory, card)


def test_checkpoint_is_small():
    directory, _ = zoo.resolve(SHIPPED)
    assert sum(p.stat().st_size for p in directory.iterdir()) < 1_000_000


def test_loads_as_sb3_policy():
    policy = zoo.load(SHIPPED)
    assert isinstance(policy, zoo.ZooPolicy)
    assert isinstance(policy.policy, ActorCriticPolicy)
    obs = np.zeros(len(OBS_NAMES), dtype=np.float32)
    action, state = policy.predict(obs, deterministic=True)
    assert action.shape == (3,) and state is None
    assert np.all(np.abs(action) <= 1.0)
    np.testing.assert_array_equal(action, policy(obs))
    batch = np.random.default_rng(0).uniform(-1, 1, (8, len(OBS_NAMES))).astype(np.float32)
    np.testing.assert_array_equal(policy.predict(batch)[0], zoo.load(SHIPPED).predict(batch)[0])


def test_card_json_is_plain_data():
    directory, _ = zoo.resolve(SHIPPED)
    json.loads((directory / "card.json").read_text())  # nothing but JSON


def test_unknown_name_is_a_clear_error():
    with pytest.raises(zoo.CheckpointError, match="neither a registered checkpoint"):
        zoo.load("no-such-checkpoint")
