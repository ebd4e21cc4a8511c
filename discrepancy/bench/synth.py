"""Synthetic "real" recordings: the twin with physics planted and hidden, driven in closed loop by the scripted
dig policy, read through faulty sensors and white measurement noise.

Used by the benchmark and the tests; the diagnosis only ever sees the returned :class:`EpisodeData` (commands,
noisy signals, phases and the nominal twin's provenance), never the planted physics.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from discrepancy.data.episode import COMPARED, ROUTE2, EpisodeData, signal_spread
from discrepancy.effects import Effect
from discrepancy.twin.env import PhysicsParams, TwinDigEnv
from discrepancy.twin.plant import apply_sensors, plan
from discrepancy.twin.spec import TwinSpec
from scaletwin_envs.policies import ScriptedDigPolicy


@dataclass
class Synthetic:
    """A planted recording: what the tool sees (``noisy``) and the truth (``clean``, before noise)."""

    noisy: EpisodeData
    clean: EpisodeData
    noise_sd: dict[str, float]


def record(twin: TwinSpec, effects: Sequence[Effect], noise: float, seed: int, extra: PhysicsParams | None = None,
           name: str = "real") -> Synthetic:
    """One closed-loop dig cycle of the twin with ``effects`` (and out-of-catalogue ``extra`` physics).

    Args:
        twin: the nominal twin (its provenance is what the recording carries).
        effects: planted catalogue effects.
        noise: white noise standard deviation per signal, as a fraction of that signal's spread.
        seed: reset seed of the episode and seed of the noise.
        extra: run-time physics to start from (out-of-catalogue terms such as ``stiffness``/``edge_drag``).
    """
    p = plan(effects, twin.soil, extra)
    env = TwinDigEnv(structure=p.structure, scale=twin.loader, soil=twin.soil, two_route_check=True,
                     **twin.env_kwargs)
    env.set_physics(p.physics)
    policy = ScriptedDigPolicy()
    policy.reset()
    obs, _ = env.reset(seed=seed)
    commands, rows, phases, times = [], [], [], []
    done = False
    while not done:
        action = np.asarray(policy(obs), dtype=np.float32)
        obs, _, terminated, truncated, info = env.step(action)
        if info.get("sim_error"):
            break
        commands.append(action.astype(np.float64))
        rows.append(info["signals"])
        phases.append(info["phase"])
        times.append(info["time"])
        done = terminated or truncated
    names = [k for k in (*COMPARED, *ROUTE2) if k in rows[0]]
    time = np.asarray(times)
    signals = apply_sensors({k: np.array([r[k] for r in rows]) for k in names}, time, p.sensors)
    clean = EpisodeData(time, np.asarray(commands), signals, np.asarray(phases, dtype=object), seed, twin.loader,
                        twin.soil, dict(twin.env_kwargs), name)
    rng = np.random.default_rng([seed, 104729])
    sd = {k: noise * v for k, v in signal_spread(signals).items()}
    noisy_signals = {k: v + sd[k] * rng.standard_normal(v.shape) for k, v in signals.items()}
    noisy = EpisodeData(time, clean.commands.copy(), noisy_signals, clean.phases.copy(), seed, twin.loader, twin.soil,
                        dict(twin.env_kwargs), name)
    return Synthetic(noisy, clean, sd)
