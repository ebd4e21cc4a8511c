"""Replaying stored commands in the twin rebuilt from provenance reproduces the recorded signals."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import mujoco
import numpy as np
import pandas as pd
import pytest

import scaletwin_envs
from scaletwin_envs.envs.wheel_loader_dig import WheelLoaderDigEnv
from scaletwin_envs.policies import ScriptedDigPolicy
from scaletwin_envs.recording import read_recording, record_episode, replay
from scaletwin_envs.recording.replay import CommandPlayback, make_twin
from scaletwin_envs.signal_units import EQ10, EQ23


def test_replay_reproduces_signals_exactly(recorded, tmp_path):
    rec = read_recording(recorded(seed=2).to_parquet(tmp_path / "ep.parquet"))
    twin = replay(rec)
    pd.testing.assert_frame_equal(twin.data, rec.data, check_exact=True)
    assert twin.provenance.source == "replay"
    assert twin.provenance.extra["replay_of"]["model_matches"] is True


def test_replay_of_a_direct_instance_with_non_default_arguments():
    env = WheelLoaderDigEnv(scale=0.3, soil="sand", pile_height=0.6, pile_distance=0.4, max_episode_time=40.0,
                            two_route_check=False)
    rec = record_episode(env, ScriptedDigPolicy(), seed=5)
    kwargs = rec.provenance.env_kwargs
    assert kwargs["pile_height"] == 0.6 and kwargs["two_route_check"] is False
    assert kwargs["max_episode_time"] == 40.0 and kwargs["energy_cost_weight"] == 0.02
    assert rec.data["F21_route2"].isna().all()  # not computed without the two-route check
    assert replay(rec).data.equals(rec.data)


def test_altered_model_is_detected_and_the_twin_differs():
    env = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    env.reset(seed=3)
    u = env.unwrapped
    u.model.body_mass[u.model.body("boom").id] *= 1.5  # the "real machine" has a heavier boom
    mujoco.mj_setConst(u.model, u.data)
    real = record_episode(env, ScriptedDigPolicy(), seed=3)
    twin = replay(real)
    assert real.provenance.model_sha256 != twin.provenance.model_sha256
    assert twin.provenance.extra["replay_of"]["model_matches"] is False
    n = min(len(real), len(twin))
    np.testing.assert_array_equal(twin.commands[:n], real.commands[:n])
    assert not np.allclose(twin.signal("F31")[:n], real.signal("F31")[:n])


def test_replay_in_a_given_env_and_errors():
    rec = record_episode(gym.make(scaletwin_envs.ENV_ID, scale="mini"), ScriptedDigPolicy(), seed=1, max_steps=20)
    assert len(rec) == 20
    assert replay(rec, env=make_twin(rec.provenance)).data.equals(rec.data)
    with pytest.raises(ValueError, match="no seed"):
        replay(type(rec)(rec.data, rec.units, type(rec.provenance)(machine=rec.provenance.machine)))
    with pytest.raises(ValueError, match="no machine spec"):
        make_twin(type(rec.provenance)())
    old = dataclasses.replace(rec.provenance, env_id="WheelLoaderDig-v0")  # a recording made before v1's physics
    with pytest.raises(ValueError, match="replaced by WheelLoaderDig-v1"):
        make_twin(old)


def test_seed_none_draws_and_stores_a_seed():
    env = gym.make(scaletwin_envs.ENV_ID, scale="mini")
    rec = record_episode(env, ScriptedDigPolicy(), max_steps=10)
    assert isinstance(rec.provenance.seed, int)
    assert replay(rec).data.equals(rec.data)


def test_command_playback_runs_out():
    play = CommandPlayback(np.zeros((2, 3)))
    play(None), play(None)
    with pytest.raises(IndexError):
        play(None)
    play.reset()
    assert play(None).shape == (3,)


def test_eq_signals_present_in_replay(recorded):
    twin = replay(recorded())
    for name in dict.fromkeys((*EQ10, *EQ23)):
        np.testing.assert_array_equal(twin.signal(name), recorded().signal(name))
