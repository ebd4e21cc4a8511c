"""What every step of a diagnosis shares: the real episode, the twin's replays, the compared signals, the null
(noise model and calibration) and the objective (a robust sum of squared whitened residuals).

A :class:`Context` is immutable: a step that re-estimates the null (around a twin with effects) returns a new one
(:meth:`Context.with_null`) rather than writing into the one it was given, so which null judged what is read off
the code. The replay cache and the :class:`~discrepancy.search.budget.Budget` it counts against are shared by
every context of one diagnosis (one owner of the replay budget: the pipeline that builds it).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from discrepancy.data.channels import COMPARED
from discrepancy.data.episode import EpisodeData, signal_spread
from discrepancy.effects import Effect, Scales
from discrepancy.search.budget import Budget
from discrepancy.stats.locate import NullCalibration, Window, windows
from discrepancy.stats.noise import NoiseModel
from discrepancy.twin.runner import CachedReplays
from discrepancy.twin.spec import SimResult

HUBER = 3.0  # whitened residuals beyond this count linearly (robust to the twin's fragile moments)
DIVERGED = 30.0  # whitened residual assigned to samples after a twin blow-up


def huber(z: np.ndarray) -> np.ndarray:
    """Huber's ρ (quadratic inside ±HUBER, linear outside), elementwise."""
    a = np.abs(z)
    return np.where(a <= HUBER, z * z, 2.0 * HUBER * a - HUBER * HUBER)


def huber_weights(z: np.ndarray) -> np.ndarray:
    """Weights of iteratively reweighted least squares for Huber's ρ: 1 inside ±HUBER, HUBER / |z| outside."""
    return np.minimum(1.0, HUBER / np.maximum(np.abs(z), 1e-12))


@dataclass(frozen=True)
class NullModel:
    """Noise model, window-statistic calibration and expected objective when nothing (more) differs
    (:func:`discrepancy.stats.null.calibrate`)."""

    noise: NoiseModel
    calibration: NullCalibration
    cost: float  # expected objective (Σ huber of whitened residuals) on noise alone
    channel_noise: dict[str, float]  # sensor noise per channel, signal units
    #: the window statistics' null under the whitening with drift (:meth:`NoiseModel.whiten_drift`)
    drift_calibration: NullCalibration | None = None
    #: what each null run moved the twin by, (runs, steps, signals), signal units, where the log leaves the twin's
    #: inputs uncertain (its start and pile, its commands' timing, its sensor filters or its time offset), so
    #: that a fitted parameter inherits that spread; None where the twin's start and inputs are the recording's
    deviations: np.ndarray | None = None
    #: the effects each null run replayed (the centre's, jittered), one tuple per run (empty around the nominal)
    run_effects: tuple[tuple[Effect, ...], ...] = ()


@dataclass(frozen=True)
class Context:
    """One real episode against its twin, judged under ``null`` (None until the null is estimated)."""

    real: EpisodeData
    replays: CachedReplays
    names: tuple[str, ...]
    real_matrix: np.ndarray
    nominal: SimResult
    scales: Scales
    budget: Budget = field(default_factory=Budget)  # replay and time limits of the searches
    null: NullModel | None = None

    def __post_init__(self) -> None:
        self.budget.spent = lambda: self.replays.runs

    @classmethod
    def build(cls, real: EpisodeData, replays: CachedReplays, budget: Budget | None = None,
              scales_of: type[Scales] = Scales) -> Context:
        """The context of ``real`` against the twin ``replays`` runs, with no null yet; ``budget`` (default: the
        default limits) counts the replays of ``replays``."""
        nominal = replays.get(())
        names = tuple(s for s in COMPARED if s in real.signals and s in nominal.signals
                      and np.all(np.isfinite(nominal.signals[s])))
        spread = signal_spread({s: nominal.signals[s] for s in names})
        twin = replays.runner.twin
        scales = scales_of.of(twin.loader, twin.soil, spread)
        return cls(real, replays, names, real.matrix(names), nominal, scales, budget or Budget())

    def with_null(self, null: NullModel) -> Context:
        """This context judged under ``null`` (same replays, same budget)."""
        return dataclasses.replace(self, null=null)

    @property
    def noise(self) -> NoiseModel | None:
        return None if self.null is None else self.null.noise

    @property
    def null_cost(self) -> float:
        """Expected objective when nothing (more) differs (0 before the null is estimated)."""
        return 0.0 if self.null is None else self.null.cost

    @property
    def drift_calibration(self) -> NullCalibration | None:
        """The null under the whitening with drift."""
        return None if self.null is None else self.null.drift_calibration

    @property
    def time(self) -> np.ndarray:
        return self.real.time

    @property
    def phases(self) -> np.ndarray:
        """The real machine's phases (the twin's where the recording has none)."""
        labels = np.asarray(self.real.phases, dtype=object)
        return labels if any(str(p) for p in labels) else self.nominal.phases

    def windows(self) -> list[Window]:
        return windows(self.phases)

    def matrix(self, result: SimResult) -> np.ndarray:
        return np.stack([result.signals[s] for s in self.names], axis=1)

    def simulate(self, effects: Sequence[Effect]) -> np.ndarray:
        return self.matrix(self.replays.get(effects))

    def simulate_many(self, effect_sets: Sequence[Sequence[Effect]]) -> list[np.ndarray]:
        return [self.matrix(r) for r in self.replays.get_many(effect_sets)]

    def z(self, twin_matrix: np.ndarray, real_matrix: np.ndarray | None = None) -> np.ndarray:
        """Whitened residual real − twin; samples after a twin blow-up get a large value."""
        assert self.null is not None, "noise model not estimated yet"
        real = self.real_matrix if real_matrix is None else real_matrix
        z = self.null.noise.whiten(real - twin_matrix)
        return np.where(np.isfinite(z), z, DIVERGED)

    def cost(self, twin_matrix: np.ndarray) -> float:
        """Objective: Σ huber(z) over all samples and compared signals."""
        return float(np.sum(huber(self.z(twin_matrix))))
