"""save_policy → load reproduces actions exactly; the per-kind builder registry; pickling reloads safely."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file
from stable_baselines3 import PPO

import scaletwin_envs
import zoo
from scaletwin_envs.recording.sweep import make_policy


@pytest.fixture(scope="module")
def tiny_model() -> PPO:
    env = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    return PPO("MlpPolicy", env, policy_kwargs={"net_arch": {"pi": [16], "vf": [8]}}, seed=3, n_steps=32,
               batch_size=16, device="cpu")


def _save(model: PPO, path: Path, **kw) -> Path:
    return zoo.save_policy(model, path, {"env_id": scaletwin_envs.ENV_ID, "env_kwargs": {}, "seed": 3}, **kw)


def test_round_trip_reproduces_actions(tiny_model: PPO, tmp_path: Path):
    directory = _save(tiny_model, tmp_path / "tiny")
    loaded = zoo.load(directory)
    obs = np.random.default_rng(1).normal(size=(32, 19)).astype(np.float32)
    np.testing.assert_array_equal(loaded.predict(obs)[0], tiny_model.predict(obs, deterministic=True)[0])
    card = json.loads((directory / "card.json").read_text())
    assert card["algorithm"] == "PPO" and card["policy_kwargs"]["net_arch"] == {"pi": [16], "vf": [8]}
    assert card["files"]["weights.safetensors"] == zoo.sha256_file(directory / "weights.safetensors")


def test_attachments_are_hashed(tiny_model: PPO, tmp_path: Path):
    note = tmp_path / "notes.txt"
    note.write_text("hello")
    directory = _save(tiny_model, tmp_path / "tiny", attachments={"notes.txt": note})
    assert zoo.card(directory)["files"]["notes.txt"] == zoo.sha256_file(note)


def test_save_refuses_to_overwrite(tiny_model: PPO, tmp_path: Path):
    _save(tiny_model, tmp_path / "tiny")
    with pytest.raises(FileExistsError):
        _save(tiny_model, tmp_path / "tiny")
    _save(tiny_model, tmp_path / "tiny", overwrite=True)


def test_register_and_load_by_name(tiny_model: PPO, tmp_path: Path):
    registry = tmp_path / "registry.json"
    directory = _save(tiny_model, tmp_path / "checkpoints" / "tiny")
    entry = zoo.register("tiny", directory, registry=registry)
    assert entry["path"] == "checkpoints/tiny" and entry["kind"] == "policy"
    assert zoo.list(registry=registry) == ["tiny"]
    assert isinstance(zoo.load("tiny", registry=registry), zoo.ZooPolicy)
    with pytest.raises(ValueError, match="names"):
        zoo.register("Bad Name", directory, registry=registry)


def test_builder_registry_plugs_in_new_kinds(tmp_path: Path):
    directory = tmp_path / "model"
    directory.mkdir()
    save_file({"w": torch.arange(3.0)}, str(directory / "w.safetensors"))
    zoo.finish_checkpoint(directory, "test-kind", {"what": "a test kind"}, ["w.safetensors"])
    with pytest.raises(zoo.CheckpointError, match="no builder for checkpoint kind 'test-kind'"):
        zoo.load(directory)
    zoo.register_builder("test-kind", lambda d, card, ref: (card["what"], load_file(d / "w.safetensors")["w"], ref))
    try:
        what, w, ref = zoo.load(directory)
        assert what == "a test kind" and w.tolist() == [0.0, 1.0, 2.0] and ref == str(directory)
        save_file({"w": torch.zeros(3)}, str(directory / "w.safetensors"))
        with pytest.raises(zoo.CheckpointError, match="sha256"):
            zoo.load(directory)
    finally:
        from zoo.loading import _BUILDERS

        _BUILDERS.pop("test-kind")


def test_pickling_reloads_from_the_checkpoint(tiny_model: PPO, tmp_path: Path):
    policy = zoo.load(_save(tiny_model, tmp_path / "tiny"))
    blob = pickle.dumps(policy)
    assert len(blob) < 1000  # a reference to the checkpoint, not its tensors
    again = pickle.loads(blob)
    obs = np.zeros(19, dtype=np.float32)
    np.testing.assert_array_equal(again(obs), policy(obs))


def test_dataset_sweep_factory_loads_the_shipped_policy():
    policy = make_policy("zoo:load_policy", name="bucketfill-ppo")
    assert isinstance(policy, zoo.ZooPolicy) and policy.ref == "bucketfill-ppo"
