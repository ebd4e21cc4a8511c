"""What residual the twin would leave if it were right: sensor noise plus the twin's own spread.

* Sensor noise per signal is estimated from the real-minus-twin residual itself (robust scale of its first
  differences, which removes slow discrepancies), floored at a small fraction of the signal's spread.
* The twin's spread comes from repeated twin runs with small seeded perturbations (:class:`NullSpec`: tiny
  friction in every joint, payload mass, start pose and pile): some moments of a dig cycle (relief valves opening,
  the bucket stalling, the reversal jerk) react strongly to anything, and residuals there mean little.

The total per-sample scale ``sigma_total`` whitens every residual the analysis looks at.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from discrepancy.effects import JOINTS, Scales, pi_unit
from discrepancy.twin.env import PhysicsParams
from discrepancy.twin.plant import Plan

MAD_TO_SD = 1.4826
NOISE_FLOOR = 1e-4  # sensor noise is at least this fraction of the signal's spread
TRIM = 3.5


@dataclass(frozen=True)
class NullSpec:
    """Repeated perturbed twin runs: how many, how large (relative), seed."""

    runs: int = 8
    size: float = 3e-4
    seed: int = 0

    def plans(self, scales: Scales) -> list[Plan]:
        """One perturbed twin per run (no structure change)."""
        out = []
        for k in range(self.runs):
            rng = np.random.default_rng([self.seed, k])
            friction = {j: abs(rng.normal()) * self.size * pi_unit("coulomb_friction", "friction", j, scales)
                        for j in JOINTS}
            physics = PhysicsParams(frictionloss=friction, payload_mass_factor=1.0 + self.size * rng.normal(),
                                    jitter=0.1 * self.size, jitter_seed=int(rng.integers(2**31)))
            out.append(Plan(physics=physics))
        return out


def sensor_noise(residual: np.ndarray, spread: np.ndarray) -> np.ndarray:
    """Noise standard deviation per column of ``residual`` (steps, signals), floored by ``spread``: the standard
    deviation of first differences / √2, after trimming differences beyond :data:`TRIM` robust deviations (steps
    of a discrepancy, fragile samples)."""
    d = np.diff(residual, axis=0)
    center = np.median(d, axis=0)
    robust = MAD_TO_SD * np.median(np.abs(d - center), axis=0)
    keep = np.abs(d - center) <= TRIM * np.maximum(robust, 1e-300)
    n = np.maximum(keep.sum(axis=0), 1)
    mean = np.sum(np.where(keep, d, 0.0), axis=0) / n
    sd = np.sqrt(np.sum(np.where(keep, (d - mean) ** 2, 0.0), axis=0) / np.maximum(n - 1, 1))
    return np.maximum(sd / np.sqrt(2.0), NOISE_FLOOR * spread)


def twin_spread(deviations: np.ndarray) -> np.ndarray:
    """RMS deviation of perturbed runs from the nominal twin, (steps, signals), widened by ±1 step.

    Args:
        deviations: (runs, steps, signals), perturbed minus nominal.
    """
    rms = np.sqrt(np.mean(deviations**2, axis=0))
    padded = np.pad(rms, ((1, 1), (0, 0)), mode="edge")
    return np.maximum(np.maximum(padded[:-2], padded[1:-1]), padded[2:])


@dataclass
class NoiseModel:
    """Per-sample scale of an unexplained residual: sqrt(sensor noise² + twin spread²) (SI, steps × signals)."""

    names: tuple[str, ...]
    sensor: np.ndarray
    twin: np.ndarray

    @property
    def total(self) -> np.ndarray:
        return np.sqrt(self.sensor[None, :] ** 2 + self.twin**2)

    def whiten(self, residual: np.ndarray) -> np.ndarray:
        """Residual (steps, signals) in units of the total scale."""
        return residual / self.total
