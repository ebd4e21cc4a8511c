"""The cylinder force signals are the force on the piston, not the servo's raw output.

``Pf_*`` must be the force the cylinder passes on to the linkage (what a pressure transducer reads), which route 2
obtains independently from the linkage's Newton–Euler equations: the servo's force less the slide's armature (oil
column) and damping forces. The legacy force-limited velocity actuator, held at relief by an overrunning load,
alternated between its force limits from one physics step to the next (the armature absorbed the difference); the
constraint servo (``scaletwin_envs.builder.SERVO_KINDS``) does not, so its raw force is the piston force but for
the armature's share.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

import scaletwin_envs  # noqa: F401
from scaletwin_envs.design_space import DesignSpace
from scaletwin_envs.physics.kinematics import LinkageUnreachable, tilt_ratio
from scaling.data.holds import make_hold_policy


def test_piston_force_is_the_transmitted_force_where_the_servo_chattered() -> None:
    """Machine 7 of the seed-1 line, carrying its load between hold poses (where the legacy servo's raw force
    jumped between its limits on > 2 % of the control steps): the servo's raw force no longer does, the reported
    Pf_tilt follows route 2 (the force the linkage receives) and, through the massless-linkage ratio, F21."""
    spec = DesignSpace().sample_one(1, 7).spec
    env = gym.make("WheelLoaderDig-v1", scale=spec, soil="gravel", two_route_check=True, max_episode_time=90.0)
    policy = make_hold_policy(seed=2_000_100, n_poses=3)
    obs, _ = env.reset(seed=5)
    raw, piston, route2, f21, linkage = [], [], [], [], []
    for _ in range(600):
        obs, _, terminated, truncated, info = env.step(policy.act(obs))
        s = info["signals"]
        raw.append(env.unwrapped.actuator_force("tilt"))
        piston.append(s["Pf_tilt"])
        route2.append(s["Pf_tilt_route2"])
        f21.append(s["F21"])
        try:
            linkage.append(tilt_ratio(spec.geometry, s["boom_angle"], s["bucket_pitch"]) * abs(s["Pf_tilt"]))
        except LinkageUnreachable:
            linkage.append(np.nan)
        if terminated or truncated:
            break
    raw, piston, route2, f21, linkage = map(np.asarray, (raw, piston, route2, f21, linkage))
    relief = spec.tilt.max_extend_force
    assert np.mean(np.abs(raw - piston) > 0.5 * relief) == 0.0  # no chatter ...
    weight = spec.weight
    assert np.mean(np.abs(piston - route2) < 1e-6 * weight) > 0.95  # ... and Pf is the transmitted force
    loaded = f21 > 0.3 * np.nanmax(f21)
    rel = np.abs(linkage - f21)[loaded] / f21[loaded]
    assert np.nanmedian(rel) < 0.02 and np.nanmean(rel < 0.1) > 0.9
