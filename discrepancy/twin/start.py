"""A field log has no reset seed: estimate the twin's start (pose and pile) from the log instead.

The seed of our own recordings fixes the start pose (boom and bucket angles) and the pile (toe distance, height,
repose angle) that the env draws at reset. A log from a real machine has none, and replaying from seed 0 puts the
pile elsewhere: the whole dig then differs and every window looks located. :func:`estimate_start` replaces the
seed by reset options (``WheelLoaderDigEnv.RESET_OPTIONS``) read from the log, fitted on the motion channels
(:data:`MOTION`), each in units of 1 % of its spread, with Huber's ρ:

* the start angles of boom and bucket by Newton on the log's first rows (the bucket has not met the pile yet);
* the pile by a coarse grid over its distance, then its repose angle (:data:`GRID` points within :data:`SPAN`
  times the half-range the env's seed draws): this finds the valley of the misfit;
* then a joint Levenberg–Marquardt over distance, repose angle and height (iteratively reweighted for Huber's ρ,
  forward-difference Jacobian). Distance and repose angle are strongly correlated (the bucket meets the slope
  where ``(x − toe)·tan(repose)`` reaches its edge: a nearer toe with a flatter slope meets it almost alike), so
  the misfit is a narrow diagonal valley in which a search one quantity at a time stalls several % short.

A pile quantity the log does not see (typically the height: a short dig never reaches the crest) has a zero column
in the Jacobian; it stays at its nominal value and is reported in :attr:`StartEstimate.unidentified`.
Every candidate is a replay; they go through the runner in batches. Whatever seed the user gives, the estimate is
the same: the options fix every quantity the seed would draw.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from discrepancy.context import HUBER, huber
from discrepancy.data.channels import COMPARED
from discrepancy.data.episode import EpisodeData
from discrepancy.twin.plant import Plan
from discrepancy.twin.runner import Runner, Start
from discrepancy.twin.spec import SimResult

GRID = 5  # grid points per pile quantity in the coarse search (each a replay)
ANGLES = ("boom_angle", "bucket_angle")
#: Channels the start angles are solved on from the log's first rows, each divided by its spread (the angles
#: themselves, or the cylinder extensions that follow from them when a log lacks an angle: without them the angles
#: were only gridded, five points over their range, and a null log without ``boom_angle`` started visibly off).
HEAD_CHANNELS = ("boom_angle", "bucket_pitch", "lift_extension", "tilt_extension")
#: The pile quantities, in the order of the coarse grid (distance first: it moves the contact most).
PILE = ("pile_distance", "repose_angle", "pile_height")
COARSE = ("pile_distance", "repose_angle")  # gridded before the joint fit (the height rarely shows; see module)
HEAD = 3  # control steps replayed to fit the start angles (before the bucket meets the pile)
NEWTON = 3  # Newton steps for the start angles
ANGLE_STEP = 1e-3  # rad, finite-difference step of the angles' Jacobian
SPAN = 2.0  # searched range, in units of the half-range the env's reset draws
#: Levenberg–Marquardt iterations (each a batch of 2·len(PILE) Jacobian replays, unless the last step was
#: rejected, and one of len(DAMPING) trial steps).
LM_ITERATIONS = 12
#: Central-difference step, in half-ranges (1.25 % of a boom length in distance, 0.5° in repose angle): the valley
#: floor is bumpy on a scale of ~1 % in distance (the contact moves by whole physics steps), and a narrow difference
#: measures a bump, so the fit stalled on one several % from the truth; this step measures the valley's trend.
FD_STEP = 0.25
#: Trial damping factors tried together per iteration, relative to the current λ (Marquardt's diag(JᵀWJ) scaling).
DAMPING = (0.1, 1.0, 10.0)
LAMBDA0 = 1e-2  # initial λ: close to Gauss–Newton (the coarse grid already put the start in the valley)
#: Converged when no step component exceeds this (half-ranges): 1 % of the seed's draw, well below what the
#: diagnosis can see.
STEP_TOL = 0.01
#: A pile quantity is unidentified when moving it by one half-range changes the scaled residual by less than this
#: in Σr² (residual units: 1 % of a channel's spread): less than one sample moved by 1 % of its spread over the
#: whole log, i.e. nothing the diagnosis could mistake for a discrepancy.
SEEN = 1.0
#: Channels the start is fitted on: the motion, which a pile met a little earlier or later shifts smoothly (the
#: forces jump at contact and make the misfit a needle around the true start).
MOTION = ("lift_extension", "tilt_extension", "boom_angle", "bucket_pitch", "travel_speed", "lift_speed",
          "tilt_speed", "x_b", "y_b")


@dataclass(frozen=True)
class StartEstimate:
    """Estimated reset options and how well the nominal twin then fits (misfit: mean Huber ρ per sample, residuals
    in units of 1 % of each channel's spread); ``unidentified``: pile quantities the log does not see (left at their
    nominal values)."""

    options: Start
    misfit: float
    misfit_default: float
    replays: int
    unidentified: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, object]:
        return {"options": dict(self.options), "misfit": self.misfit, "misfit_default": self.misfit_default,
                "replays": self.replays, "unidentified": list(self.unidentified)}


def _nominal(env_kwargs: dict[str, object], soil_repose: float) -> dict[str, tuple[float, float]]:
    """Centre and half-range of each start quantity as the env draws it (see ``WheelLoaderDigEnv.reset_model``):
    angles in rad, distance and height in boom lengths, repose angle in rad."""
    noise = float(env_kwargs.get("reset_noise_scale", 1.0))  # type: ignore[arg-type]
    distance = float(env_kwargs.get("pile_distance", 0.5))  # type: ignore[arg-type]
    height = float(env_kwargs.get("pile_height", 0.7))  # type: ignore[arg-type]
    return {"boom_angle": (0.015 * noise, 0.015 * max(noise, 0.2)),
            "bucket_angle": (0.0, 0.03 * max(noise, 0.2)),
            "pile_distance": (distance, 0.05 * max(noise, 0.2)),
            "pile_height": (height, 0.08 * height * max(noise, 0.2)),
            "repose_angle": (soil_repose, math.radians(2.0) * max(noise, 0.2))}


class _Fit:
    """The log's motion channels against replays from candidate starts: residual vectors and their misfit."""

    def __init__(self, ep: EpisodeData, runner: Runner, skip: int) -> None:
        names = [s for s in MOTION if s in ep.signals and np.all(np.isfinite(ep.signals[s]))] or \
            [s for s in COMPARED if s in ep.signals and np.all(np.isfinite(ep.signals[s]))]
        self.ep, self.runner, self.skip, self.names = ep, runner, skip, names
        self.scale = np.array([max(0.01 * float(np.ptp(ep.signals[s])), 1e-12) for s in names])
        self.replays = 0

    def residuals(self, result: SimResult) -> np.ndarray | None:
        """(twin − log) / scale over the rows after ``skip``, flattened; None when the replay failed."""
        if result.error:
            return None
        z = np.stack([(result.signals[s][self.skip:] - self.ep.signals[s][self.skip:]) / self.scale[j]
                      for j, s in enumerate(self.names)], axis=1)
        return np.nan_to_num(z, nan=1e3).ravel()

    def run(self, starts: list[Start]) -> list[np.ndarray | None]:
        """Residuals of one replay per start (one batch through the runner)."""
        self.replays += len(starts)
        results = self.runner.run_many(self.ep.commands, [Plan()] * len(starts), starts=starts)
        return [self.residuals(r) for r in results]


def misfit(z: np.ndarray | None) -> float:
    """Mean Huber ρ of residuals ``z`` (units of 1 % of a channel's spread; inf for a failed replay): residuals
    beyond :data:`~discrepancy.context.HUBER` units count linearly (a discrepancy, not the start)."""
    return math.inf if z is None else float(np.mean(huber(z)))


def estimate_start(ep: EpisodeData, runner: Runner, skip: int = 0) -> StartEstimate:
    """Reset options for the twin of ``runner`` that best replay ``ep`` (see the module), ignoring its first
    ``skip`` rows (rows a time offset left without a logged value)."""
    twin = runner.twin
    fit = _Fit(ep, runner, skip)
    centre = _nominal(dict(twin.env_kwargs), twin.soil.repose_angle)
    current = {k: c for k, (c, _) in centre.items()}
    default = misfit(fit.run([_start(current)])[0])
    angles_seen = len(_head_channels(ep)) >= len(ANGLES)
    if angles_seen:
        fit.replays += _solve_angles(ep, runner, current, skip)
    z: np.ndarray | None = None
    for name in COARSE if angles_seen else (*ANGLES, *COARSE):
        c, half = centre[name]
        grid = np.linspace(c - SPAN * half, c + SPAN * half, GRID)
        grid = grid[grid > 0.0] if name in PILE else grid
        runs = fit.run([_start({**current, name: float(v)}) for v in grid])
        k = int(np.argmin([misfit(r) for r in runs]))
        z, current[name] = runs[k], float(grid[k])
    best, unidentified = _levenberg_marquardt(fit, centre, current, z)
    return StartEstimate(_start(current), float(best), float(default), fit.replays, unidentified)


def _levenberg_marquardt(fit: _Fit, centre: dict[str, tuple[float, float]], current: dict[str, float],
                         z: np.ndarray | None) -> tuple[float, tuple[str, ...]]:
    """Joint Levenberg–Marquardt over :data:`PILE` from ``current`` (residuals ``z`` there; updated in place), in
    units of each quantity's half-range, kept within :data:`SPAN` of the nominal value; IRLS weights for Huber's ρ.
    Returns the misfit reached and the quantities the log does not see (:data:`SEEN`)."""
    half = np.array([centre[k][1] for k in PILE])
    mid = np.array([centre[k][0] for k in PILE])

    def start_at(u: np.ndarray) -> Start:
        return _start({**current, **dict(zip(PILE, (mid + half * u).tolist(), strict=True))})

    u = np.array([(current[k] - centre[k][0]) / centre[k][1] for k in PILE])
    best, lam, seen = misfit(z), LAMBDA0, np.zeros(len(PILE), dtype=bool)
    jac: np.ndarray | None = None
    for _ in range(LM_ITERATIONS):
        if z is None:
            break
        if jac is None:  # a new point: its Jacobian (kept while trial steps from it are rejected)
            eye = np.eye(len(PILE))
            runs = fit.run([start_at(u + FD_STEP * e) for e in eye] + [start_at(u - FD_STEP * e) for e in eye])
            probes = [p for p in runs if p is not None]
            if len(probes) < len(runs):
                break
            n = len(PILE)
            jac = np.stack([(probes[i] - probes[n + i]) / (2 * FD_STEP) for i in range(n)], axis=1)
            seen |= np.sum(jac**2, axis=0) >= SEEN
        if not seen.any():
            break
        w = np.minimum(1.0, HUBER / np.maximum(np.abs(z), 1e-12))  # IRLS weights of Huber's ρ
        a = jac[:, seen].T @ (w[:, None] * jac[:, seen])
        g = jac[:, seen].T @ (w * z)
        trials = []
        for f in DAMPING:
            step = np.zeros(len(PILE))
            step[seen] = -np.linalg.solve(a + lam * f * np.diag(np.diag(a)), g)
            trials.append(np.clip(u + step, -SPAN, SPAN))
        results = fit.run([start_at(t) for t in trials])
        costs = [misfit(r) for r in results]
        k = int(np.argmin(costs))
        if costs[k] >= best:
            if max(float(np.max(np.abs(t - u))) for t in trials) < STEP_TOL:
                break  # converged: even the longest step is negligible and does not help
            lam *= DAMPING[-1] ** 2  # no trial helped: damp harder (shorter steps) from the same point
            continue
        done = float(np.max(np.abs(trials[k] - u))) < STEP_TOL
        u, z, best, lam, jac = trials[k], results[k], costs[k], lam * DAMPING[k], None
        if done:
            break
    current.update(zip(PILE, (mid + half * u).tolist(), strict=True))
    return best, tuple(k for k, s in zip(PILE, seen, strict=True) if not s)


def _solve_angles(ep: EpisodeData, runner: Runner, current: dict[str, float], skip: int = 0) -> int:
    """Start angles of boom and bucket (rad) from the log's first rows: Gauss–Newton on the first :data:`HEAD` control
    steps of the :data:`HEAD_CHANNELS` it has, each relative to its spread (cheap replays; the pile is not met yet),
    finite-difference Jacobian; updates ``current``, returns replays."""
    rows = slice(skip, skip + HEAD)
    names = _head_channels(ep)
    scale = np.array([max(float(np.ptp(ep.signals[c])), 1e-12) for c in names])[:, None]
    target = (np.array([ep.signals[c][rows] for c in names]) / scale).ravel()
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
        y = [(np.array([r.signals[c][rows] for c in names]) / scale).ravel() for r in results]
        jac = np.stack([(y[1] - y[0]) / ANGLE_STEP, (y[2] - y[0]) / ANGLE_STEP], axis=1)
        step, *_ = np.linalg.lstsq(jac, target - y[0], rcond=None)
        x = np.clip(x + step, -0.3, 0.3)
        current["boom_angle"], current["bucket_angle"] = float(x[0]), float(x[1])
        if np.max(np.abs(step)) < 1e-5:
            break
    return replays


def _head_channels(ep: EpisodeData) -> list[str]:
    """The :data:`HEAD_CHANNELS` the log has, finite throughout."""
    return [c for c in HEAD_CHANNELS if c in ep.signals and np.all(np.isfinite(ep.signals[c]))]


def _start(values: dict[str, float]) -> Start:
    return tuple(sorted((k, float(v)) for k, v in values.items()))
