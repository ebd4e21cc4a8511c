"""Locate: per signal × dig phase × time window, where the residual exceeds what noise and the twin's own spread
explain, with an effect size and a calibrated p-value controlled across all tests (Benjamini–Hochberg).

Statistic of a window w of signal s: T = Σ z², z the residual whitened by :class:`~discrepancy.stats.noise.NoiseModel`.
Its null distribution is learnt from the perturbed twin runs (each scored like a recording, with synthetic sensor
noise and the spread of the other runs): per signal a scaled chi-square a·χ²(b·n) matched to the null moments,
which gives continuous p-values far into the tail. Effect size: sqrt(max(T / E0[T] − 1, 0)), the RMS excess of
the residual over its null RMS (0 when nothing differs).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy import stats

WINDOW = 10  # control steps per window at most
ALPHA = 0.01  # false discovery rate across all signal × window tests


@dataclass(frozen=True)
class Window:
    """Rows [start, stop) of one dig phase."""

    phase: str
    start: int
    stop: int

    @property
    def size(self) -> int:
        return self.stop - self.start


@dataclass(frozen=True)
class Located:
    """A significant window: ``p_value`` is BH-adjusted (≤ alpha); times in s (first and last sample)."""

    signal: str
    phase: str
    t_start: float
    t_end: float
    effect_size: float
    p_value: float

    def to_dict(self) -> dict[str, float | str]:
        return {"signal": self.signal, "phase": self.phase, "t_start": self.t_start, "t_end": self.t_end,
                "effect_size": self.effect_size, "p_value": self.p_value}


def windows(phases: np.ndarray, max_len: int = WINDOW) -> list[Window]:
    """Contiguous runs of one phase, cut into windows of at most ``max_len`` rows (the last may be shorter)."""
    out: list[Window] = []
    start = 0
    labels = [str(p) or "unknown" for p in phases]
    for k in range(1, len(labels) + 1):
        if k == len(labels) or labels[k] != labels[start]:
            run = range(start, k)
            pieces = max(1, int(np.ceil(len(run) / max_len)))
            edges = np.linspace(start, k, pieces + 1).round().astype(int)
            out.extend(Window(labels[start], int(a), int(b)) for a, b in itertools.pairwise(edges))
            start = k
    return out


def window_stats(z: np.ndarray, wins: list[Window]) -> np.ndarray:
    """Σ z² per window and signal, (windows, signals)."""
    return np.stack([np.sum(z[w.start:w.stop] ** 2, axis=0) for w in wins])


@dataclass
class NullCalibration:
    """Per-signal scaled chi-square a·χ²(b·n) of the window statistic under the null."""

    a: np.ndarray
    b: np.ndarray

    @classmethod
    def fit(cls, null_stats: list[np.ndarray], sizes: np.ndarray) -> NullCalibration:
        """Moments of T/n over all null runs and windows, per signal (method of moments)."""
        t = np.concatenate(null_stats, axis=0)  # (runs × windows, signals)
        n = np.tile(sizes, len(null_stats))[:, None].astype(float)
        m1 = np.mean(t / n, axis=0)
        m2 = np.mean((t - m1 * n) ** 2 / n, axis=0)
        a = np.maximum(m2 / (2.0 * np.maximum(m1, 1e-300)), 1e-12)
        b = np.maximum(m1 / a, 1e-6)
        return cls(a, b)

    def expected(self, sizes: np.ndarray) -> np.ndarray:
        """E0[T] per window and signal."""
        return (self.a * self.b)[None, :] * sizes[:, None]

    def p_values(self, t: np.ndarray, sizes: np.ndarray) -> np.ndarray:
        return stats.chi2.sf(t / self.a[None, :], self.b[None, :] * sizes[:, None])


def benjamini_hochberg(p: np.ndarray) -> np.ndarray:
    """BH-adjusted p-values (same shape), over all entries (``scipy.stats.false_discovery_control``)."""
    return stats.false_discovery_control(p.ravel(), method="bh").reshape(p.shape)


@dataclass
class LocateResult:
    """All tests (windows × signals): statistic, effect size, raw and adjusted p; and the significant ones."""

    wins: list[Window]
    names: tuple[str, ...]
    stat: np.ndarray
    effect: np.ndarray
    p: np.ndarray
    q: np.ndarray
    located: list[Located]

    def pairs(self) -> set[tuple[str, str]]:
        """(signal, phase) pairs with at least one located window."""
        return {(loc.signal, loc.phase) for loc in self.located}


def locate(z: np.ndarray, time: np.ndarray, wins: list[Window], names: tuple[str, ...], calib: NullCalibration,
           alpha: float = ALPHA) -> LocateResult:
    """Test every window of every signal of the whitened residual ``z`` (steps, signals)."""
    sizes = np.array([w.size for w in wins])
    t = window_stats(z, wins)
    expected = calib.expected(sizes)
    effect = np.sqrt(np.maximum(t / expected - 1.0, 0.0))
    p = calib.p_values(t, sizes)
    q = benjamini_hochberg(p)
    found = [Located(names[j], w.phase, float(time[w.start]), float(time[w.stop - 1]), float(effect[i, j]),
                     float(q[i, j]))
             for i, w in enumerate(wins) for j in range(len(names)) if q[i, j] <= alpha]
    found.sort(key=lambda loc: (loc.p_value, -loc.effect_size))
    return LocateResult(wins, names, t, effect, p, q, found)
