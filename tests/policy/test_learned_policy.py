"""The shipped learned policy fills the bucket at the miniature and at the WA475 (gravel, deterministic)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import scaletwin_envs
import zoo
from scaletwin_envs.physics.bucket import heaped_capacity
from scaletwin_envs.recording.recorder import record_episode
from scaletwin_envs.rollout import run_episode
from scaletwin_envs.specs import make_loader, make_soil

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
    """The recording of a learned cycle is that cycle: its commands, final fill, loaded mass, hydraulic work and
    time are those of the same seeded episode rolled out without the recorder, and they agree with each other
    (m_load = fill × heaped capacity × bulk density; work = Σ dt Σ max(Pf·v, 0) over the recorded cylinder signals)."""
    env = gym.make(scaletwin_envs.ENV_ID, scale="er12", soil="gravel")
    recording = record_episode(env, learned, seed=0, policy_name="zoo:bucketfill-ppo")
    episode = run_episode(gym.make(scaletwin_envs.ENV_ID, scale="er12", soil="gravel"), learned, seed=0)
    kpis, data = episode.kpis, recording.data
    assert kpis is not None and kpis.sim_error is None and kpis.success
    assert recording.provenance.seed == 0 and recording.provenance.policy == "zoo:bucketfill-ppo"
    assert len(recording) == kpis.steps == len(episode.actions)
    np.testing.assert_array_equal(data[["cmd_lift", "cmd_tilt", "cmd_drive"]].to_numpy(), np.array(episode.actions))
    last = data.iloc[-1]
    assert last["m_load"] == pytest.approx(kpis.loaded_mass, rel=1e-12)
    assert last["fill_factor"] == pytest.approx(kpis.fill_factor, rel=1e-12) and kpis.fill_factor >= FILL_THRESHOLD
    assert last["hydraulic_work"] == pytest.approx(kpis.hydraulic_work, rel=1e-12)
    assert last["time"] == pytest.approx(kpis.cycle_time, rel=1e-12)
    spec, soil = make_loader("er12"), make_soil("gravel")
    dt = float(env.unwrapped.dt)
    np.testing.assert_allclose(data["time"], dt * data["step"], rtol=1e-9)
    capacity = heaped_capacity(spec.geometry)
    np.testing.assert_allclose(data["m_load"], data["fill_factor"] * capacity * soil.density, rtol=1e-9)
    power = sum(np.maximum(data[f"Pf_{k}"] * data[f"{k}_speed"], 0.0) for k in ("lift", "tilt"))
    np.testing.assert_allclose(data["hydraulic_work"], np.cumsum(power * dt), rtol=1e-9)
    phases = list(dict.fromkeys(data["phase"]))
    assert phases[:3] == ["approach", "penetrate", "curl"], phases
