"""The twin env with no planted physics reproduces WheelLoaderDig-v1 exactly (built, as the twin is, with the legacy
actuator servo, ``scaletwin_envs.builder.SERVO_KINDS``)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

import scaletwin_envs
from discrepancy.twin.env import PhysicsParams, Structure, TwinDigEnv
from scaletwin_envs.envs.wheel_loader_dig import WheelLoaderDigEnv
from scaletwin_envs.policies import ScriptedDigPolicy
from scaletwin_envs.rollout import run_episode


class _LegacyServoDig(WheelLoaderDigEnv):
    SERVO = "actuator"


def test_nominal_twin_equals_env() -> None:
    assert TwinDigEnv.SERVO == "actuator"
    a = run_episode(_LegacyServoDig(scale="mini"), ScriptedDigPolicy(), seed=2)
    b = run_episode(TwinDigEnv(scale="mini"), ScriptedDigPolicy(), seed=2)
    assert len(a.infos) == len(b.infos)
    for k in ("F21", "Pf_lift", "bucket_pitch"):
        assert np.array_equal(a.signal(k), b.signal(k))


def test_twin_keeps_its_timestep_and_the_env_its_own() -> None:
    """The twin divides the mini's Froude step into 3 (the legacy servo's rule); the env runs at the Froude step."""
    twin, env = TwinDigEnv(scale="mini"), gym.make(scaletwin_envs.ENV_ID, scale="mini").unwrapped
    assert twin.model.opt.timestep == env.model.opt.timestep / 3


def test_structure_is_checked() -> None:
    env = TwinDigEnv(scale="mini")
    try:
        env.set_physics(PhysicsParams(clearance={"pin_O": 1e-3}))
    except ValueError as exc:
        assert "Structure" in str(exc)
    else:
        raise AssertionError("clearance without a play joint was accepted")
    env2 = TwinDigEnv(structure=Structure(play_pins=("pin_O",), compliant=("tilt",)), scale="mini")
    env2.set_physics(PhysicsParams(clearance={"pin_O": 1e-3}, compliance={"tilt": 1e-6}))
    env2.reset(seed=0)
    *_, info = env2.step(np.zeros(3))
    assert info["sim_error"] is None
