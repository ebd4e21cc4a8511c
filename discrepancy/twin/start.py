"""A field log has no reset seed: estimate the twin's start (pose and pile) from the log instead.

The seed of our own recordings fixes the start pose (boom and bucket angles) and the pile (toe distance, height,
repose angle) that the env draws at reset. A log from a real machine has none, and replaying from seed 0 puts the
pile elsewhere: the whole dig then differs and every window looks located. :func:`estimate_start` replaces the
seed by reset options (``WheelLoaderDigEnv.RESET_OPTIONS``) read from the log:

* a coordinate search over the start angles of boom and bucket and the pile's distance, height and repose angle,
  within twice the range the env's seed draws (:data:`SPAN`), minimising a robust misfit of the motion channels
  (:data:`MOTION`), each scaled by its spread: a grid, then golden-section steps around its best point.

Every candidate is a replay (:data:`GRID` per pile quantity and sweep); they go through the runner in batches.
Whatever seed the user gives, the estimate is the same: the options fix every quantity the seed would draw.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from discrepancy.context import huber
from discrepancy.data.channels import COMPARED
from discrepancy.data.episode import EpisodeData
from discrepancy.twin.plant import Plan
from discrepancy.twin.runner import Runner, Start
from discrepancy.twin.spec import SimResult

GRID = 5  # candidates per pile quantity and sweep (contact timing makes the misfit step-like between them)
ANGLES = ("boom_angle", "bucket_angle")
HEAD = 3  # control steps replayed to fit the start angles (before the bucket meets the pile)
NEWTON = 3  # Newton steps for the start angles
ANGLE_STEP = 1e-3  # rad, finite-difference step of the angles' Jacobian
SWEEPS = 2  # coordinate sweeps over the three pile quantities
REFINE = 5  # golden-section steps around the best grid point
#: Channels the start is fitted on: the motion, which a pile met a little earlier or later shifts smoothly (the
#: forces jump at contact and make the misfit a needle around the true start).
MOTION = ("lift_extension", "tilt_extension", "boom_angle", "bucket_pitch", "travel_speed", "lift_speed",
          "tilt_speed", "x_b", "y_b")
SPAN = 2.0  # searched range, in units of the half-range the env's reset draws


@dataclass(frozen=True)
class StartEstimate:
    """Estimated reset options and how well the nominal twin then fits (misfit per sample, 1 % of spread units)."""

    options: Start
    misfit: float
    misfit_default: float
    replays: int

    def to_dict(self) -> dict[str, object]:
        return {"options": dict(self.options), "misfit": self.misfit, "misfit_default": self.misfit_default,
                "replays": self.replays}


def _nominal(env_kwargs: dict[str, object], soil_repose: float) -> dict[str, tuple[float, float]]:
    """Centre and half-range of each pile quantity as the env draws it (see ``WheelLoaderDigEnv.reset_model``)."""
    noise = float(env_kwargs.get("reset_noise_scale", 1.0))  # type: ignore[arg-type]
    distance = float(env_kwargs.get("pile_distance", 0.5))  # type: ignore[arg-type]
    height = float(env_kwargs.get("pile_height", 0.7))  # type: ignore[arg-type]
    return {"boom_angle": (0.015 * noise, 0.015 * max(noise, 0.2)),
            "bucket_angle": (0.0, 0.03 * max(noise, 0.2)),
            "pile_distance": (distance, 0.05 * max(noise, 0.2)),
            "pile_height": (height, 0.08 * height * max(noise, 0.2)),
            "repose_angle": (soil_repose, math.radians(2.0) * max(noise, 0.2))}


def _misfit(ep: EpisodeData, result: SimResult, names: list[str], scale: np.ndarray, skip: int = 0) -> float:
    if result.error:
        return math.inf
    z = np.stack([(ep.signals[s][skip:] - result.signals[s][skip:]) / scale[j] for j, s in enumerate(names)], axis=1)
    # Huber's ρ: residuals beyond 3 units (3 % of a channel's spread) count linearly (a discrepancy, not the start)
    return float(np.mean(huber(np.nan_to_num(z, nan=1e3))))


def estimate_start(ep: EpisodeData, runner: Runner, skip: int = 0) -> StartEstimate:
    """Reset options for the twin of ``runner`` that best replay ``ep`` (see the module), ignoring its first
    ``skip`` rows (rows a time offset left without a logged value)."""
    twin = runner.twin
    names = [s for s in MOTION if s in ep.signals and np.all(np.isfinite(ep.signals[s]))] or \
        [s for s in COMPARED if s in ep.signals and np.all(np.isfinite(ep.signals[s]))]
    scale = np.array([max(0.01 * float(np.ptp(ep.signals[s])), 1e-12) for s in names])
    commands = ep.commands
    replays = 0

    def run(starts: list[Start]) -> list[float]:
        nonlocal replays
        replays += len(starts)
        results = runner.run_many(commands, [Plan()] * len(starts), starts=starts)
        return [_misfit(ep, r, names, scale, skip) for r in results]

    centre = _nominal(dict(twin.env_kwargs), twin.soil.repose_angle)
    current = {k: c for k, (c, _) in centre.items()}
    default = run([_start(current)])[0]
    if {"boom_angle", "bucket_pitch"} <= set(ep.signals):
        replays += _solve_angles(ep, runner, current, skip)
    best = default
    for _ in range(SWEEPS):
        for name, (c, half) in centre.items():
            if name in ANGLES and {"boom_angle", "bucket_pitch"} <= set(ep.signals):
                continue
            grid = np.linspace(c - SPAN * half, c + SPAN * half, GRID)
            grid = grid[grid > 0.0]
            costs = run([_start({**current, name: float(v)}) for v in grid])
            k = int(np.argmin(costs))
            if costs[k] < best:
                best, current[name] = costs[k], float(grid[k])
            lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
            for _ in range(REFINE):  # golden section on [lo, hi] around the best point
                a, b = hi - 0.618 * (hi - lo), lo + 0.618 * (hi - lo)
                fa, fb = run([_start({**current, name: float(a)}), _start({**current, name: float(b)})])
                if min(fa, fb) < best:
                    best, current[name] = (fa, float(a)) if fa <= fb else (fb, float(b))
                lo, hi = (lo, b) if fa <= fb else (a, hi)
    return StartEstimate(_start(current), float(best), float(default), replays)


def _solve_angles(ep: EpisodeData, runner: Runner, current: dict[str, float], skip: int = 0) -> int:
    """Start angles of boom and bucket from the log's first rows: Newton on the first :data:`HEAD` control steps
    (cheap replays; the pile is not met yet), finite-difference Jacobian; updates ``current``, returns replays."""
    rows = slice(skip, skip + HEAD)
    target = np.array([ep.signals["boom_angle"][rows], ep.signals["bucket_pitch"][rows]]).ravel()
    head = ep.commands[:skip + HEAD]
    replays = 0
    for _ in range(NEWTON):
        x = np.array([current["boom_angle"], current["bucket_angle"]])
        trial = [x, x + np.array([ANGLE_STEP, 0.0]), x + np.array([0.0, ANGLE_STEP])]
        results = runner.run_many(head, [Plan()] * 3,
                                  starts=[_start({**current, "boom_angle": float(t[0]), "bucket_angle": float(t[1])})
                                          for t in trial])
        replays += 3
        if any(r.error for r in results):
            break
        y = [np.array([r.signals["boom_angle"][rows], r.signals["bucket_pitch"][rows]]).ravel() for r in results]
        jac = np.stack([(y[1] - y[0]) / ANGLE_STEP, (y[2] - y[0]) / ANGLE_STEP], axis=1)
        step, *_ = np.linalg.lstsq(jac, target - y[0], rcond=None)
        x = np.clip(x + step, -0.3, 0.3)
        current["boom_angle"], current["bucket_angle"] = float(x[0]), float(x[1])
        if np.max(np.abs(step)) < 1e-5:
            break
    return replays


def _start(values: dict[str, float]) -> Start:
    return tuple(sorted((k, float(v)) for k, v in values.items()))
