"""Intervals that stay honest off the training machines: split conformal over whole machines.

Rows of one machine are not exchangeable with rows of another (a machine shares its design, hence its errors),
so a residual quantile taken over rows of the training machines under-covers on a machine never seen. Here the
calibration set is a set of *machines* held out of training (grouped split), and every calibration machine
weighs the same in the quantile whatever its row count, so the interval is calibrated for "a new machine of the
line", the unit a user meets. The nonconformity score is normalised by a per-row scale (the ensemble's spread, or
1), which lets the width follow the input (Lei et al. 2018, normalised split conformal; Barber et al. 2021 for the
grouped setting). A hand-written weighted quantile is used because the library implementations (mapie, crepes)
weigh rows, not groups, and need a scikit-learn estimator; δ1 models here are fitted on pair data sets.

``ExtrapolationScore`` is the distance of a machine's design descriptor to its nearest training machines,
standardised by the training machines' own spread; it warns when the target lies outside the design space the
model saw (threshold: a quantile of the calibration machines' scores).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


def group_weighted_quantile(scores: np.ndarray, groups: np.ndarray, level: float, *,
                            finite_sample: bool = False) -> float:
    """The ``level`` quantile of ``scores`` with every group weighing the same (each row 1/n_group).

    ``finite_sample=True`` raises the level to min(1, level·(G + 1)/G) for G groups, the split-conformal correction
    when each group is one exchangeable unit: with fewer than level/(1 − level) groups (9 at 90 %) it returns the
    largest score, which certifies coverage but is uselessly wide. The default is the plain weighted quantile, whose
    coverage of a new group's rows holds as the number of calibration groups grows (Barber et al. 2021, §6).
    """
    s, g = np.asarray(scores, dtype=float), np.asarray(groups).astype(str)
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level}")
    ok = np.isfinite(s)
    s, g = s[ok], g[ok]
    if s.size == 0:
        raise ValueError("no finite calibration scores")
    names, inverse, counts = np.unique(g, return_inverse=True, return_counts=True)
    w = 1.0 / counts[inverse]
    w = w / w.sum()
    order = np.argsort(s)
    cdf = np.cumsum(w[order])
    n_groups = len(names)
    target = min(1.0, level * (n_groups + 1) / n_groups) if finite_sample else level
    return float(s[order][min(int(np.searchsorted(cdf, target - 1e-12)), s.size - 1)])


@dataclass
class GroupConformal:
    """Normalised split-conformal interval on a log-scale prediction, calibrated over machine groups.

    ``fit(residual, scale, groups)`` takes ``residual = ln(actual) − ln(predicted)`` on calibration machines never
    used in training, ``scale`` > 0 per row (e.g. the ensemble's standard deviation of ln δ1; ones for a point
    model) and the machine of each row. ``interval(log_pred, scale)`` returns the bounds on the log scale.
    """

    coverage: float = 0.9
    finite_sample: bool = False
    quantile_: float | None = None
    n_groups_: int = 0

    def fit(self, residual: np.ndarray, scale: np.ndarray, groups: np.ndarray) -> GroupConformal:
        if not 0 < self.coverage < 1:
            raise ValueError(f"coverage must be in (0, 1), got {self.coverage}")
        r, sc = np.asarray(residual, dtype=float), np.asarray(scale, dtype=float)
        if r.shape != sc.shape or r.shape[0] != len(groups):
            raise ValueError("residual, scale and groups must have one entry per row")
        if np.any(sc[np.isfinite(sc)] <= 0):
            raise ValueError("scales must be > 0")
        self.quantile_ = group_weighted_quantile(np.abs(r) / sc, np.asarray(groups), self.coverage,
                                                 finite_sample=self.finite_sample)
        self.n_groups_ = len(set(np.asarray(groups).astype(str)))
        return self

    def interval(self, log_pred: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) on the log scale."""
        if self.quantile_ is None:
            raise RuntimeError("GroupConformal is not fitted")
        half = self.quantile_ * np.asarray(scale, dtype=float)
        return np.asarray(log_pred) - half, np.asarray(log_pred) + half


@dataclass
class ExtrapolationScore:
    """Mean distance of a design descriptor to its ``k`` nearest training machines, in units of the training
    machines' own nearest-neighbour distance (1 ≈ as close as training machines are to each other)."""

    k: int = 3
    warn_quantile: float = 0.95
    mean_: np.ndarray | None = None
    std_: np.ndarray | None = None
    train_: np.ndarray | None = None
    unit_: float = 1.0
    threshold_: float = float("inf")

    def fit(self, descriptors: np.ndarray) -> ExtrapolationScore:
        x = np.asarray(descriptors, dtype=float)
        if x.ndim != 2 or x.shape[0] <= self.k:
            raise ValueError(f"need more than k={self.k} training machines, got {x.shape[0]}")
        self.mean_, self.std_ = x.mean(axis=0), x.std(axis=0)
        self.std_[self.std_ == 0] = 1.0
        self.train_ = (x - self.mean_) / self.std_
        d = np.linalg.norm(self.train_[:, None, :] - self.train_[None, :, :], axis=-1)
        np.fill_diagonal(d, np.inf)
        self.unit_ = float(np.mean(np.sort(d, axis=1)[:, : self.k]))
        return self

    def score(self, descriptors: np.ndarray) -> np.ndarray:
        if self.train_ is None or self.mean_ is None or self.std_ is None:
            raise RuntimeError("ExtrapolationScore is not fitted")
        z = (np.atleast_2d(np.asarray(descriptors, dtype=float)) - self.mean_) / self.std_
        d = np.linalg.norm(z[:, None, :] - self.train_[None, :, :], axis=-1)
        return np.mean(np.sort(d, axis=1)[:, : self.k], axis=1) / self.unit_

    def calibrate(self, descriptors: np.ndarray) -> ExtrapolationScore:
        """Set the warning threshold at :attr:`warn_quantile` of held-out machines' scores (inside the space)."""
        self.threshold_ = float(np.quantile(self.score(descriptors), self.warn_quantile))
        return self

    def warns(self, descriptors: np.ndarray) -> np.ndarray:
        return self.score(descriptors) > self.threshold_


def auroc(score: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve of ``score`` for ``positive`` (ties counted half); NaN without both classes."""
    s, y = np.asarray(score, dtype=float), np.asarray(positive, dtype=bool)
    pos, neg = s[y], s[~y]
    if pos.size == 0 or neg.size == 0:
        return float("nan")
    ranks = _ranks(np.concatenate([pos, neg]))
    return float((ranks[: pos.size].sum() - pos.size * (pos.size + 1) / 2) / (pos.size * neg.size))


def _ranks(x: np.ndarray) -> np.ndarray:
    from scipy.stats import rankdata

    return rankdata(x)


def coverage_by_group(actual: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                      groups: Sequence[str] | np.ndarray) -> dict[str, float]:
    """Fraction of rows inside [lower, upper] per group."""
    a, g = np.asarray(actual, dtype=float), np.asarray(groups).astype(str)
    inside = (a >= np.asarray(lower)) & (a <= np.asarray(upper))
    return {str(n): float(np.mean(inside[g == n])) for n in np.unique(g)}
