"""Scorers of a candidate group set: how strongly the target group relates to the other groups.

One interface, :meth:`Scorer.score`, selected by name (:data:`SCORERS`, :func:`get_scorer`) or passed as an object:
the paper's filter :class:`PearsonRMS` (RMS over the non-target groups of the Pearson correlation with ``pi1``),
:class:`SpearmanRMS`, :class:`MutualInformation` (KSG) and :class:`CrossValidatedR2`. Ranking sets with a
shuffled-data baseline is :func:`scaling.dimensions.selection.rank_pi_sets`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Literal

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import digamma
from scipy.stats import rankdata


class Scorer(ABC):
    """Strategy: how strongly a target group relates to the other groups of a set (higher = stronger)."""

    name: str = "scorer"
    min_rows: int = 3

    @abstractmethod
    def score(self, target_values: np.ndarray, group_values: np.ndarray) -> float:
        """Score one set. ``target_values``: shape ``(n,)``; ``group_values``: ``(n, m)``, m >= 0 other groups;
        all finite and inside :meth:`domain`. Returns a finite float (0.0 when ``m == 0``)."""

    def domain(self, target_values: np.ndarray, group_values: np.ndarray) -> np.ndarray:
        """Boolean mask of usable rows; by default rows where every value is finite."""
        return np.isfinite(target_values) & np.isfinite(group_values).all(axis=1)


def _correlations(t: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Pearson r of ``t`` with each column of ``g``; a constant column (or target) gives r = 0, not NaN."""
    tc, gc = t - t.mean(), g - g.mean(axis=0)
    denom = np.sqrt((tc**2).sum() * (gc**2).sum(axis=0))
    with np.errstate(invalid="ignore", divide="ignore"):
        r = (tc @ gc) / denom
    return np.where(denom > 0, np.clip(r, -1.0, 1.0), 0.0)


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values.size else 0.0


class PearsonRMS(Scorer):
    """The paper's filter: RMS over non-target groups of Pearson r(pi1, pi_j), in [0, 1].

    Pearson r is not invariant to inverting a group (r(x, y) != -r(x, 1/y)), while a set holds each group only in
    its canonical orientation (see :class:`scaling.dimensions.pi_theorem.PiSet`). ``orientation="best"`` (default)
    scores each group in the orientation with the larger |r|, i.e. the paper's filter applied to all ``2**(k-1)``
    orientations of the set, keeping the best; zero-valued groups are then outside the domain. ``"canonical"`` scores
    the groups as given. ``log=True`` correlates ``log|pi|`` instead (any power of a group scores the same; zeros
    dropped).
    """

    name = "pearson"

    def __init__(self, orientation: Literal["best", "canonical"] = "best", log: bool = False) -> None:
        if orientation not in ("best", "canonical"):
            raise ValueError(f"orientation must be 'best' or 'canonical', got {orientation!r}")
        self.orientation, self.log = orientation, log

    def domain(self, target_values: np.ndarray, group_values: np.ndarray) -> np.ndarray:
        mask = super().domain(target_values, group_values)
        if self.log:
            mask &= target_values != 0
        if self.log or self.orientation == "best":
            mask &= (group_values != 0).all(axis=1)
        return mask

    def score(self, target_values: np.ndarray, group_values: np.ndarray) -> float:
        if self.log:
            return _rms(_correlations(np.log(np.abs(target_values)), np.log(np.abs(group_values))))
        r = np.abs(_correlations(target_values, group_values))
        if self.orientation == "best":
            r = np.maximum(r, np.abs(_correlations(target_values, 1.0 / group_values)))
        return _rms(r)


class SpearmanRMS(Scorer):
    """RMS of Spearman rank correlations: invariant to monotone transforms (``Re`` vs ``1/Re`` score the same)."""

    name = "spearman"

    def score(self, target_values: np.ndarray, group_values: np.ndarray) -> float:
        if group_values.shape[1] == 0:
            return 0.0
        return _rms(_correlations(rankdata(target_values), rankdata(group_values, axis=0)))


class MutualInformation(Scorer):
    """Kraskov-Stoegbauer-Grassberger (KSG, estimator 1) mutual information in nats, on rank-transformed data.

    ``joint=True``: I(pi1; pi2..pik) of the whole set. ``joint=False``: RMS over groups of max(I(pi1; pi_j), 0).
    Ranks (copula transform; MI is invariant to monotone maps) plus a 1e-10 deterministic jitter break ties;
    at most ``max_rows`` rows (an evenly spaced subsample) are used to bound the O(n log n) cost.
    """

    name = "mi"

    def __init__(self, k: int = 3, joint: bool = True, max_rows: int = 2000) -> None:
        self.k, self.joint, self.max_rows = k, joint, max_rows
        self.min_rows = k + 2

    def score(self, target_values: np.ndarray, group_values: np.ndarray) -> float:
        if group_values.shape[1] == 0:
            return 0.0
        idx = np.linspace(0, len(target_values) - 1, min(len(target_values), self.max_rows)).astype(int)
        t, g = _copula(target_values[idx, None]), _copula(group_values[idx])
        if self.joint:
            return _ksg(t, g, self.k)
        return _rms(np.array([max(_ksg(t, g[:, [j]], self.k), 0.0) for j in range(g.shape[1])]))


def _copula(x: np.ndarray) -> np.ndarray:
    jitter = np.random.default_rng(0).standard_normal(x.shape) * 1e-10
    return rankdata(x, axis=0) / len(x) + jitter


def _ksg(x: np.ndarray, y: np.ndarray, k: int) -> float:
    """KSG estimator 1 of I(x; y) with the max-norm; x: (n, dx), y: (n, dy)."""
    n = len(x)
    eps = cKDTree(np.hstack([x, y])).query(np.hstack([x, y]), k=k + 1, p=np.inf)[0][:, -1]
    radius = np.nextafter(eps, 0)
    nx = cKDTree(x).query_ball_point(x, radius, p=np.inf, return_length=True) - 1
    ny = cKDTree(y).query_ball_point(y, radius, p=np.inf, return_length=True) - 1
    return float(digamma(k) + digamma(n) - np.mean(digamma(nx + 1) + digamma(ny + 1)))


class CrossValidatedR2(Scorer):
    """Out-of-fold R^2 of a least-squares fit of pi1 on the other groups (with intercept).

    ``log=True`` (default) fits the power law ``log|pi1| = c + sum a_j log|pi_j|`` (rows with a zero value are
    outside the domain and dropped); ``log=False`` fits ``pi1`` linearly on the raw groups. Folds are
    ``n_folds`` contiguous blocks (time-ordered data are not leaked across folds); R^2 = 1 - SSE_oof / SST,
    pooled over folds, so it can be negative.
    """

    name = "cv_r2"

    def __init__(self, n_folds: int = 5, log: bool = True) -> None:
        self.n_folds, self.log = n_folds, log
        self.min_rows = 2 * n_folds

    def domain(self, target_values: np.ndarray, group_values: np.ndarray) -> np.ndarray:
        mask = super().domain(target_values, group_values)
        if self.log:
            mask &= (target_values != 0) & (group_values != 0).all(axis=1)
        return mask

    def score(self, target_values: np.ndarray, group_values: np.ndarray) -> float:
        y, x = target_values, group_values
        if self.log:
            y, x = np.log(np.abs(y)), np.log(np.abs(x))
        design = np.column_stack([np.ones(len(y)), x])
        sst = float(np.sum((y - y.mean()) ** 2))
        if group_values.shape[1] == 0 or sst == 0:
            return 0.0
        sse = 0.0
        for test in np.array_split(np.arange(len(y)), self.n_folds):
            train = np.setdiff1d(np.arange(len(y)), test)
            coef = np.linalg.lstsq(design[train], y[train], rcond=None)[0]
            sse += float(np.sum((y[test] - design[test] @ coef) ** 2))
        return 1.0 - sse / sst


SCORERS: dict[str, type[Scorer]] = {c.name: c for c in (PearsonRMS, SpearmanRMS, MutualInformation, CrossValidatedR2)}


def get_scorer(scorer: str | Scorer) -> Scorer:
    """A scorer object from a name in :data:`SCORERS` (default settings) or the object itself."""
    if isinstance(scorer, Scorer):
        return scorer
    if scorer not in SCORERS:
        raise ValueError(f"unknown scorer {scorer!r}; choose one of {sorted(SCORERS)} or pass a Scorer")
    return SCORERS[scorer]()
