"""Run one dig episode with any policy and summarise it: the per-step trace and the standard KPIs."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

Policy = Callable[[np.ndarray], np.ndarray]


@dataclass
class EpisodeKPIs:
    """Standard loading KPIs of one dig cycle (SI)."""

    fill_factor: float  # loaded volume / rated heaped volume
    loaded_mass: float  # kg
    cycle_time: float  # s
    cycle_time_froude: float  # cycle time / sqrt(L/g)
    hydraulic_work: float  # J, pump work into both cylinder circuits
    specific_energy: float  # J/kg of load (inf for an empty bucket)
    spilled_mass: float  # kg
    success: bool  # fill factor reached the env's success_fill and the cycle completed
    sim_error: str | None
    steps: int

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class Episode:
    """A finished episode: actions, observations, ``info`` per step, and KPIs."""

    actions: list[np.ndarray] = field(default_factory=list)
    observations: list[np.ndarray] = field(default_factory=list)
    infos: list[dict[str, Any]] = field(default_factory=list)
    kpis: EpisodeKPIs | None = None

    def signal(self, name: str) -> np.ndarray:
        """One signal over the episode (one value per step after reset)."""
        return np.array([info["signals"][name] for info in self.infos])

    def peaks(self, names: tuple[str, ...] = ("F21", "F31", "Pf_lift", "Pf_tilt", "a1", "alpha1")) -> dict[str, float]:
        return {n: float(np.max(np.abs(self.signal(n)))) for n in names}


def run_episode(env: gym.Env, policy: Policy | Any, seed: int | None = None,
                on_step: Callable[[int, np.ndarray, dict[str, Any]], None] | None = None) -> Episode:
    """Roll out ``policy`` (a callable obs → action, or anything with SB3's ``predict``) until the episode ends."""
    act = _as_callable(policy)
    if hasattr(policy, "reset"):
        policy.reset()
    obs, info = env.reset(seed=seed)
    ep = Episode(observations=[obs])
    if on_step is not None:
        on_step(0, np.zeros(env.action_space.shape), info)
    terminated = truncated = False
    while not (terminated or truncated):
        action = np.asarray(act(obs), dtype=np.float32)
        obs, _, terminated, truncated, info = env.step(action)
        ep.actions.append(action)
        ep.observations.append(obs)
        ep.infos.append(info)
        if on_step is not None:
            on_step(len(ep.actions), action, info)
    ep.kpis = _kpis(env, ep, terminated)
    return ep


def _as_callable(policy: Any) -> Policy:
    if hasattr(policy, "predict") and not hasattr(policy, "act"):
        return lambda obs: policy.predict(obs, deterministic=True)[0]
    return policy


def _kpis(env: gym.Env, ep: Episode, completed: bool) -> EpisodeKPIs:
    u = env.unwrapped
    last = ep.infos[-1] if ep.infos else {}
    good = [i for i in ep.infos if not i.get("sim_error")]
    final = good[-1] if good else {}
    loaded = float(final.get("loaded_mass", 0.0))
    work = float(final.get("hydraulic_work", 0.0))
    t = float(final.get("time", 0.0))
    return EpisodeKPIs(
        fill_factor=float(final.get("fill_factor", 0.0)), loaded_mass=loaded, cycle_time=t,
        cycle_time_froude=t / u.loader.froude_time, hydraulic_work=work,
        specific_energy=work / loaded if loaded > 0 else float("inf"),
        spilled_mass=float(final.get("spilled_mass", 0.0)),
        success=bool(completed and final.get("success", False)), sim_error=last.get("sim_error"),
        steps=len(ep.infos),
    )
