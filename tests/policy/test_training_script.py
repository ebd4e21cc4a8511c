"""The training script runs end to end on a tiny budget and writes a loadable, verified checkpoint."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np

import zoo

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "examples" / "train_bucket_fill.py"
CONFIG = ROOT / "examples" / "bucket_fill_ppo.json"


def _script():
    spec = importlib.util.spec_from_file_location("train_bucket_fill", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _tiny_config(path: Path) -> Path:
    cfg = json.loads(CONFIG.read_text())
    cfg["behaviour_cloning"].update(teacher_episodes=2, dagger_rounds=1, dagger_episodes=1, first_epochs=2,
                                    round_epochs=1, critic_epochs=1)
    cfg["policy_kwargs"]["net_arch"] = {"pi": [8], "vf": [8]}
    cfg["ppo"].update(n_envs=1, n_steps=64, batch_size=32, n_epochs=1)
    cfg["budget"] = {"ppo_timesteps": 64, "validate_every": 64}
    cfg["validation"].update(scales=["mini"], soils=["gravel"], episodes=1)
    cfg["evaluation"].update(scales=["mini"], soils=["gravel"], episodes=1)
    path.write_text(json.dumps(cfg))
    return path


def test_shipped_config_is_complete():
    cfg = json.loads(CONFIG.read_text())
    for key in ("seed", "env", "teacher", "policy_kwargs", "behaviour_cloning", "ppo", "budget", "validation",
                "evaluation"):
        assert key in cfg, key
    assert cfg["env"]["randomization"]["scale_range"] == [0.05, 3.0]
    assert set(cfg["env"]["randomization"]["soils"]) == {"gravel", "sand", "sandy_loam", "clay_loam"}


def test_tiny_training_run(tmp_path: Path):
    out = tmp_path / "tiny-ppo"
    assert _script().main(["--config", str(_tiny_config(tmp_path / "cfg.json")), "--out", str(out),
                           "--no-register"]) == 0
    card = zoo.card(out)
    assert card["algorithm"] == "PPO" and card["training"]["config"]["seed"] == 0
    assert {"behaviour_cloning_s", "ppo_s", "total_s"} <= set(card["training"]["wall_time"])
    assert "mini/gravel" in card["metrics"]["per_cell"]
    assert set(card["files"]) == {"weights.safetensors", "training.rrd"}
    policy = zoo.load(out)
    assert policy.predict(np.zeros(19, dtype=np.float32))[0].shape == (3,)
