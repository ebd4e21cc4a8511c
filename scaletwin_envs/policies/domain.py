"""Domain randomisation for training one policy at every size: a new machine and soil every episode.

:class:`RandomizedDigEnv` re-makes the inner ``WheelLoaderDig-v1`` on every ``reset`` with keyword arguments
drawn by a :class:`ScaleSoilSampler`: a preset machine with some probability, otherwise a length ratio
log-uniform over the supported range under a scaling law drawn from ``laws``; the soil uniform over the named
soils. Building the env costs ~3 ms, a few control steps. Everything is drawn from one generator seeded by
``reset(seed=...)``, so a seeded run is reproducible episode by episode.

Registered as ``WheelLoaderDigRandom-v1`` (entry point :func:`make_randomized_dig_env`), with the sampler's fields
and the inner env's arguments as keyword arguments of ``gym.make``::

    env = gym.make("WheelLoaderDigRandom-v1", scale_range=(0.1, 2.0), soils=("sand", "gravel"),
                   laws=("product_line", "froude"), two_route_check=False)

A drawn law applies to drawn length ratios only; a drawn preset is built as it is (``info["law"]`` still reports
the draw, so the draws stay the same whatever the outcome).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

import scaletwin_envs
from scaletwin_envs.envs.wheel_loader_dig import horizon_steps
from scaletwin_envs.specs import make_loader
from scaletwin_envs.specs.laws import LAWS, PRODUCT_LINE
from scaletwin_envs.specs.presets import PRESETS
from scaletwin_envs.specs.soil import SOILS

#: The length ratios (vs the ER12) that ``WheelLoaderDig-v1`` accepts.
SCALE_RANGE = (0.05, 3.0)
#: Keyword arguments of :func:`make_randomized_dig_env` that configure the :class:`ScaleSoilSampler`.
SAMPLER_FIELDS = ("scale_range", "soils", "laws", "presets", "preset_probability")
#: Inner env arguments the sampler draws (they cannot be fixed through ``env_kwargs``).
DRAWN_KWARGS = ("scale", "soil", "law")


@dataclass(frozen=True)
class ScaleSoilSampler:
    """Draws env keyword arguments ``scale``, ``law`` and ``soil`` (see the module docstring).

    Attributes:
        scale_range: length ratios vs the ER12, drawn log-uniformly.  laws: scaling laws of drawn ratios.
        soils: soil names, drawn uniformly.  presets: preset machines, drawn with ``preset_probability``.
    """

    scale_range: tuple[float, float] = SCALE_RANGE
    soils: tuple[str, ...] = tuple(SOILS)
    laws: tuple[str, ...] = ("product_line",)
    presets: tuple[str, ...] = ()
    preset_probability: float = 0.0

    def __post_init__(self) -> None:
        lo, hi = self.scale_range
        if not (SCALE_RANGE[0] <= lo <= hi <= SCALE_RANGE[1]):
            raise ValueError(f"scale_range must lie within {SCALE_RANGE}, got {self.scale_range}")
        for what, given, known in (("soils", self.soils, SOILS), ("laws", self.laws, LAWS)):
            if not given or set(given) - set(known):
                raise ValueError(f"{what} must be a non-empty subset of {sorted(known)}, got {given}")
        if set(self.presets) - set(PRESETS) or not 0.0 <= self.preset_probability <= (1.0 if self.presets else 0.0):
            raise ValueError(f"presets must be a subset of {sorted(PRESETS)} and preset_probability in [0, 1] "
                             f"(0 without presets), got {self.presets}, {self.preset_probability}")

    def sample(self, rng: np.random.Generator) -> dict[str, Any]:
        lo, hi = self.scale_range
        scale: float | str = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
        law = str(self.laws[int(rng.integers(len(self.laws)))])
        if self.presets and rng.uniform() < self.preset_probability:
            scale = str(self.presets[int(rng.integers(len(self.presets)))])
        return {"scale": scale, "soil": str(self.soils[int(rng.integers(len(self.soils)))]), "law": law}


class RandomizedDigEnv(gym.Wrapper):
    """``WheelLoaderDig-v1`` re-made with sampled scale and soil on every reset (see module docstring).

    Args:
        sampler: what to draw.  env_kwargs: further env arguments, the same every episode.
        seed: seed of the draws (``reset(seed=...)`` reseeds them).
    """

    def __init__(self, sampler: ScaleSoilSampler | None = None, env_kwargs: Mapping[str, Any] | None = None,
                 seed: int | None = None) -> None:
        self.sampler = sampler or ScaleSoilSampler()
        self.env_kwargs = dict(env_kwargs or {})
        self._rng = np.random.default_rng(seed)
        self.drawn = self.sampler.sample(self._rng)  # kwargs of the current episode's machine and soil
        super().__init__(self._make(self.drawn))

    def _make(self, drawn: Mapping[str, Any]) -> gym.Env:
        kwargs = {**self.env_kwargs, **drawn}
        if not isinstance(kwargs["scale"], int | float):
            kwargs.pop("law", None)  # a preset machine is built as it is; the env rejects a law for it
        loader = None
        if kwargs.get("frame_skip") is not None:  # physics steps at this machine's timestep: the horizon needs it
            loader = make_loader(kwargs["scale"], kwargs.get("law", PRODUCT_LINE), kwargs.get("distortion"))
        steps = horizon_steps(kwargs.get("max_episode_time", 60.0), kwargs.get("frame_skip"), loader,
                              kwargs.get("timestep"))
        return gym.make(scaletwin_envs.ENV_ID, max_episode_steps=steps, disable_env_checker=True, **kwargs)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        self.drawn = self.sampler.sample(self._rng)
        self.env.close()
        self.env = self._make(self.drawn)
        obs, info = self.env.reset(seed=int(self._rng.integers(2**31 - 1)), options=options)
        return obs, {**info, **self.drawn}


def make_randomized_dig_env(sampler: ScaleSoilSampler | None = None, env_kwargs: Mapping[str, Any] | None = None,
                            seed: int | None = None, **kwargs: Any) -> RandomizedDigEnv:
    """Entry point of ``WheelLoaderDigRandom-v1``: a :class:`RandomizedDigEnv` from flat keyword arguments.

    Args:
        sampler: a ready sampler; or give its fields (:data:`SAMPLER_FIELDS`: ``scale_range`` as length ratios vs the
            ER12, ``soils``, ``laws``, ``presets``, ``preset_probability``) as keyword arguments.
        env_kwargs: inner env arguments; any other keyword argument is one too (e.g. ``two_route_check=False``,
            ``render_mode="rgb_array"``). ``scale``, ``soil`` and ``law`` are drawn and raise ``ValueError``.
        seed: seed of the draws (``reset(seed=...)`` reseeds them).
    """
    fields = {k: kwargs.pop(k) for k in SAMPLER_FIELDS if k in kwargs}
    inner = {**dict(env_kwargs or {}), **kwargs}
    fixed = sorted(set(DRAWN_KWARGS) & set(inner))
    if fixed:
        raise ValueError(f"{fixed} are drawn every episode; choose them through {list(SAMPLER_FIELDS)} (or use "
                         f"{scaletwin_envs.ENV_ID} for one machine and soil)")
    if fields and sampler is not None:
        raise ValueError(f"give either sampler= or its fields {sorted(fields)}, not both")
    if sampler is None:
        sampler = ScaleSoilSampler(**{k: v if k == "preset_probability" else tuple(v) for k, v in fields.items()})
    return RandomizedDigEnv(sampler, inner, seed)


class CompletionBonus(gym.Wrapper):
    """Training-side shaping: when the dig cycle completes (the env terminates), add ``weight × fill factor``.

    The env's own reward pays for fill as it is gained, whether or not the bucket is ever carried out; this
    term pays again for the fill actually delivered, so a policy learns to finish the cycle (it appears as
    ``info["reward_terms"]["completion"]``). The env itself is unchanged.
    """

    def __init__(self, env: gym.Env, weight: float) -> None:
        if not (math.isfinite(weight) and weight >= 0):
            raise ValueError(f"weight must be a finite number >= 0, got {weight!r}")
        super().__init__(env)
        self.weight = float(weight)

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if terminated:
            bonus = self.weight * float(info.get("fill_factor", 0.0))
            info = {**info, "reward_terms": {**info.get("reward_terms", {}), "completion": bonus}}
            reward = float(reward) + bonus
        return obs, reward, terminated, truncated, info
