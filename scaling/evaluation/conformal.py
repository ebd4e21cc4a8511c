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
standardised by the training machines' own spread; it says when the target *machine* lies outside the design space
the model saw (threshold: a quantile of the calibration machines' scores). It does not say which *rows* to
distrust: on the product-line benchmark its AUROC for rows more than 10 % off was 0.3–0.56, no better than chance.

``ErrorScore`` does better: the probability that a prediction is more than ``miss`` off, from what is known before
the truth: the model's own spread (an ensemble's σ of ln δ1), how far the row's input groups lie from the training
rows (``InputNovelty``, nearest-neighbour distance), how large a correction the model applies (|ln δ1|) and the
design distance. A logistic regression on those features, fitted on the calibration machines (every machine
weighing the same) and judged on machines it never saw; its warning threshold keeps the warnings to at most 5 % of
the rows on 90 % of the calibration machines (:func:`machine_level_quantile`). The benchmark reports it beside the
served risk.

``RowInterval`` is the interval a checkpoint serves per row: a learnt width and a bound covering 90 % of the rows
of the median calibration machine, chosen leaving each calibration machine out in turn. ``IntervalRisk`` reads the
served risk off the same interval: the probability that a row is more than ``miss`` off is the share of the median
calibration machine's rows whose residual, in units of their width, lies beyond the miss line in units of this
row's width; it warns where that is at least one half (:class:`RowRisk` serves it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

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
    w = machine_weights(g)
    order = np.argsort(s)
    cdf = np.cumsum(w[order])
    n_groups = len(np.unique(g))
    target = min(1.0, level * (n_groups + 1) / n_groups) if finite_sample else level
    return float(s[order][min(int(np.searchsorted(cdf, target - 1e-12)), s.size - 1)])


def machine_level_quantile(scores: np.ndarray, groups: np.ndarray, level: float, machine_share: float) -> float:
    """The score bound that covers ``level`` of the rows of ``machine_share`` of the groups (machines).

    Every group's own ``level`` quantile is taken, then the ``machine_share`` quantile of those (linear
    interpolation over the groups). Where the pooled :func:`group_weighted_quantile` covers ``level`` of the rows
    of an *average* new machine, and so under-covers the machines whose errors are larger than the calibration
    machines' typical ones, this bound is a tolerance statement per machine: "at least ``level`` of a new machine's
    rows, for ``machine_share`` of new machines". It is wider, and the price is over-coverage on the easy machines.
    """
    s, g = np.asarray(scores, dtype=float), np.asarray(groups).astype(str)
    if not 0 < level < 1 or not 0 < machine_share <= 1:
        raise ValueError(f"level must be in (0, 1) and machine_share in (0, 1], got {level}, {machine_share}")
    ok = np.isfinite(s)
    s, g = s[ok], g[ok]
    names = np.unique(g)
    if names.size < 2:
        raise ValueError(f"a machine-level bound needs at least two calibration machines, got {names.size}")
    per_machine = np.array([np.quantile(s[g == n], level) for n in names])
    return float(np.quantile(per_machine, machine_share))


def calibration_bound(scores: np.ndarray, groups: np.ndarray, level: float, machine_share: float | None, *,
                      finite_sample: bool = False) -> float:
    """The bound on ``scores`` that holds ``level`` of the rows: of an average machine (``machine_share`` None,
    :func:`group_weighted_quantile`, with its ``finite_sample`` option) or of ``machine_share`` of the machines
    (:func:`machine_level_quantile`)."""
    if machine_share is None:
        return group_weighted_quantile(scores, groups, level, finite_sample=finite_sample)
    return machine_level_quantile(scores, groups, level, machine_share)


def machine_weights(groups: np.ndarray) -> np.ndarray:
    """Row weights summing to 1 with every group (machine) weighing the same, whatever its row count."""
    _, inverse, counts = np.unique(np.asarray(groups).astype(str), return_inverse=True, return_counts=True)
    w = 1.0 / counts[inverse]
    return w / w.sum()


def standardisation(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(mean, standard deviation) of the columns of ``x``; a constant column gets 1 (it stays constant)."""
    mean, std = x.mean(axis=0), x.std(axis=0)
    std[std == 0] = 1.0
    return mean, std


def _calibration_rows(features: np.ndarray, values: np.ndarray, groups: np.ndarray,
                      name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rows of (features, values, groups) whose features and value are finite.

    Raises:
        ValueError: the three do not have one entry per row, or no row is finite.
    """
    x, v = np.atleast_2d(np.asarray(features, dtype=float)), np.asarray(values, dtype=float)
    g = np.asarray(groups).astype(str)
    if not x.shape[0] == v.shape[0] == g.shape[0]:
        raise ValueError(f"features, {name} and groups must have one entry per row")
    ok = np.isfinite(x).all(axis=1) & np.isfinite(v)
    if not ok.any():
        raise ValueError("no finite calibration rows")
    return x[ok], v[ok], g[ok]


@dataclass
class GroupConformal:
    """Normalised split-conformal interval on a log-scale prediction, calibrated over machine groups.

    ``fit(residual, scale, groups)`` takes ``residual = ln(actual) − ln(predicted)`` on calibration machines never
    used in training, ``scale`` > 0 per row (e.g. the ensemble's standard deviation of ln δ1; ones for a point
    model) and the machine of each row. ``interval(log_pred, scale)`` returns the bounds on the log scale.

    ``machine_share`` (None: off) switches from the pooled quantile (``coverage`` of the rows of an average new
    machine) to the machine-level bound of :func:`machine_level_quantile` (``coverage`` of the rows of
    ``machine_share`` of new machines).
    """

    coverage: float = 0.9
    finite_sample: bool = False
    machine_share: float | None = None
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
        self.quantile_ = calibration_bound(np.abs(r) / sc, np.asarray(groups), self.coverage, self.machine_share,
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
class ResidualScale:
    """A per-row scale for :class:`GroupConformal`: exp of a linear model of ln |residual| on per-row features
    (the error score's), fitted with every machine weighing the same and ridge ``l2`` on standardised features.

    :meth:`cross_fit` returns each calibration machine's scales from a model fitted on the *other* calibration
    machines, so that the conformal quantile is taken on scores the scale model did not see (cross-fitting);
    the model kept is then fitted on all of them.
    """

    l2: float = 1e-2
    floor: float = 1e-4
    mean_: np.ndarray | None = None
    std_: np.ndarray | None = None
    coef_: np.ndarray | None = None

    def fit(self, features: np.ndarray, residual: np.ndarray, groups: np.ndarray) -> ResidualScale:
        x, r, g = _calibration_rows(features, residual, groups, "residual")
        y = np.log(np.maximum(np.abs(r), self.floor))
        self.mean_, self.std_ = standardisation(x)
        z = np.column_stack([np.ones(len(x)), (x - self.mean_) / self.std_])
        w = machine_weights(g)
        penalty = self.l2 * np.eye(z.shape[1])
        penalty[0, 0] = 0.0
        self.coef_ = np.linalg.solve(z.T @ (z * w[:, None]) + penalty, z.T @ (w * y))
        return self

    def scale(self, features: np.ndarray) -> np.ndarray:
        """Scale per row (> 0; the median scale where a feature is not finite)."""
        if self.coef_ is None or self.mean_ is None or self.std_ is None:
            raise RuntimeError("ResidualScale is not fitted")
        x = np.atleast_2d(np.asarray(features, dtype=float))
        z = np.nan_to_num((x - self.mean_) / self.std_)
        return np.exp(self.coef_[0] + z @ self.coef_[1:])

    def state(self) -> dict[str, Any]:
        """JSON-able parameters of a fitted instance (:meth:`from_state` rebuilds it)."""
        if self.coef_ is None or self.mean_ is None or self.std_ is None:
            raise RuntimeError("ResidualScale is not fitted")
        return {"l2": self.l2, "floor": self.floor, "mean": self.mean_.tolist(), "std": self.std_.tolist(),
                "coef": self.coef_.tolist()}

    @classmethod
    def from_state(cls, params: dict[str, Any]) -> ResidualScale:
        out = cls(l2=float(params["l2"]), floor=float(params["floor"]))
        out.mean_, out.std_, out.coef_ = (np.asarray(params[k], dtype=float) for k in ("mean", "std", "coef"))
        if not out.mean_.shape == out.std_.shape == (out.coef_.shape[0] - 1,):
            raise ValueError("residual-scale parameters of inconsistent lengths")
        return out

    def cross_fit(self, features: np.ndarray, residual: np.ndarray, groups: np.ndarray) -> np.ndarray:
        """Out-of-machine scales for the calibration rows; leaves ``self`` fitted on all rows."""
        g = np.asarray(groups).astype(str)
        names = np.unique(g)
        if names.size < 2:
            raise ValueError("cross-fitting needs at least two calibration machines")
        out = np.empty(g.shape[0])
        for name in names:
            held = g == name
            part = ResidualScale(self.l2, self.floor).fit(features[~held], residual[~held], g[~held])
            out[held] = part.scale(features[held])
        self.fit(features, residual, g)
        return out


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
        self.mean_, self.std_ = standardisation(x)
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


@dataclass
class InputNovelty:
    """Mean distance of rows to their ``k`` nearest training rows in standardised input space, in units of the
    training rows' own nearest-neighbour distance (1 ≈ as close as training rows are to each other).

    Inputs are group values (any sign, any magnitude): each column is mapped by asinh(x / median |x|) before
    standardising, so that a group spanning decades is compared on a log-like scale. At most ``max_rows``
    training rows are kept (a seeded draw) to keep the tree small.
    """

    k: int = 8
    max_rows: int = 20_000
    seed: int = 0
    scale_: np.ndarray | None = None
    mean_: np.ndarray | None = None
    std_: np.ndarray | None = None
    unit_: float = 1.0
    tree_: Any = None

    def _z(self, x: np.ndarray) -> np.ndarray:
        assert self.scale_ is not None and self.mean_ is not None and self.std_ is not None
        return (np.arcsinh(np.asarray(x, dtype=float) / self.scale_) - self.mean_) / self.std_

    def fit(self, x: np.ndarray) -> InputNovelty:
        from scipy.spatial import cKDTree

        a = np.asarray(x, dtype=float)
        a = a[np.isfinite(a).all(axis=1)] if a.ndim == 2 else a
        if a.ndim != 2 or a.shape[0] <= self.k:
            raise ValueError(f"need a 2-D array of more than k={self.k} finite rows, got shape {np.shape(x)}")
        if a.shape[0] > self.max_rows:
            a = a[np.random.default_rng(self.seed).choice(a.shape[0], self.max_rows, replace=False)]
        med = np.median(np.abs(a), axis=0)
        self.scale_ = np.where(med > 0, med, 1.0)
        self.mean_, self.std_ = standardisation(np.arcsinh(a / self.scale_))
        z = self._z(a)
        self.tree_ = cKDTree(z)
        d, _ = self.tree_.query(z, k=self.k + 1)  # the first neighbour is the row itself
        self.unit_ = float(np.median(d[:, 1:].mean(axis=1))) or 1.0
        return self

    def state(self) -> tuple[dict[str, Any], np.ndarray]:
        """(JSON-able parameters, the kept training rows in standardised space) of a fitted instance."""
        if self.tree_ is None or self.scale_ is None or self.mean_ is None or self.std_ is None:
            raise RuntimeError("InputNovelty is not fitted")
        return ({"k": self.k, "max_rows": self.max_rows, "seed": self.seed, "scale": self.scale_.tolist(),
                 "mean": self.mean_.tolist(), "std": self.std_.tolist(), "unit": self.unit_},
                np.asarray(self.tree_.data, dtype=float))

    @classmethod
    def from_state(cls, params: dict[str, Any], rows: np.ndarray) -> InputNovelty:
        """The fitted instance of :meth:`state` (the tree rebuilt from the rows)."""
        from scipy.spatial import cKDTree

        out = cls(k=int(params["k"]), max_rows=int(params["max_rows"]), seed=int(params["seed"]))
        out.scale_, out.mean_, out.std_ = (np.asarray(params[k], dtype=float) for k in ("scale", "mean", "std"))
        out.unit_ = float(params["unit"])
        z = np.asarray(rows, dtype=float)
        if z.ndim != 2 or z.shape[1] != out.scale_.shape[0] or z.shape[0] <= out.k:
            raise ValueError(f"novelty rows of shape {z.shape} do not fit {out.scale_.shape[0]} features, k={out.k}")
        out.tree_ = cKDTree(z)
        return out

    def score(self, x: np.ndarray) -> np.ndarray:
        if self.tree_ is None:
            raise RuntimeError("InputNovelty is not fitted")
        z = np.nan_to_num(self._z(np.atleast_2d(x)), nan=1e6, posinf=1e6, neginf=-1e6)
        d, _ = self.tree_.query(z, k=self.k)
        return d.mean(axis=1) / self.unit_


@dataclass
class ErrorScore:
    """Probability that a prediction is more than ``miss`` off, by logistic regression on per-row features
    (module docstring), every calibration machine weighing the same; ``warns`` above a threshold set on the
    calibration scores: by default the machine-level bound of :func:`machine_level_quantile` (at most
    1 − ``warn_quantile`` of the rows warned on ``machine_share`` of the calibration machines), with
    ``machine_share=None`` the pooled machine-weighted ``warn_quantile`` (that share of the rows of an average
    machine). The pooled threshold warned on a median 9 % of the rows of held-out machines, mostly on rows that were
    fine; the machine-level one keeps the warnings to the machines and rows that stand out.

    Features are passed as columns already on a sensible scale (logs of spreads and distances); they are
    standardised on the calibration rows. ``l2`` is the ridge penalty on the standardised coefficients.
    """

    miss: float = 0.10
    warn_quantile: float = 0.95
    l2: float = 1e-2
    machine_share: float | None = 0.9
    mean_: np.ndarray | None = None
    std_: np.ndarray | None = None
    coef_: np.ndarray | None = None
    threshold_: float = float("inf")

    def fit(self, features: np.ndarray, error: np.ndarray, groups: np.ndarray) -> ErrorScore:
        """``error``: relative error |pred − actual| / actual per row (NaN rows ignored)."""
        from scipy.optimize import minimize

        x, e, g = _calibration_rows(features, error, groups, "error")
        y = e > self.miss
        if y.all() or not y.any():
            raise ValueError(f"calibration rows are all on one side of the {self.miss:.0%} miss line: nothing to "
                             "learn an error score from")
        self.mean_, self.std_ = standardisation(x)
        z = np.column_stack([np.ones(len(x)), (x - self.mean_) / self.std_])
        w = machine_weights(g)
        sign = np.where(y, 1.0, -1.0)

        def loss(beta: np.ndarray) -> tuple[float, np.ndarray]:
            m = sign * (z @ beta)
            value = float(np.sum(w * np.logaddexp(0.0, -m))) + self.l2 * float(beta[1:] @ beta[1:])
            p = 0.5 * (1.0 - np.tanh(0.5 * m))  # = 1 / (1 + exp(m)), overflow-free
            grad = -(z * (w * sign * p)[:, None]).sum(axis=0)
            grad[1:] += 2.0 * self.l2 * beta[1:]
            return value, grad

        self.coef_ = minimize(loss, np.zeros(z.shape[1]), jac=True, method="L-BFGS-B").x
        share = self.machine_share if np.unique(g).size >= 2 else None  # one machine: nothing to bound per machine
        self.threshold_ = calibration_bound(self.score(x), g, self.warn_quantile, share)
        return self

    def state(self) -> dict[str, Any]:
        """JSON-able parameters of a fitted instance (:meth:`from_state` rebuilds it)."""
        if self.coef_ is None or self.mean_ is None or self.std_ is None:
            raise RuntimeError("ErrorScore is not fitted")
        return {"miss": self.miss, "warn_quantile": self.warn_quantile, "l2": self.l2,
                "machine_share": self.machine_share, "mean": self.mean_.tolist(), "std": self.std_.tolist(),
                "coef": self.coef_.tolist(), "threshold": self.threshold_}

    @classmethod
    def from_state(cls, params: dict[str, Any]) -> ErrorScore:
        share = params.get("machine_share")
        out = cls(miss=float(params["miss"]), warn_quantile=float(params["warn_quantile"]), l2=float(params["l2"]),
                  machine_share=None if share is None else float(share))
        out.mean_, out.std_, out.coef_ = (np.asarray(params[k], dtype=float) for k in ("mean", "std", "coef"))
        if not out.mean_.shape == out.std_.shape == (out.coef_.shape[0] - 1,):
            raise ValueError("error-score parameters of inconsistent lengths")
        out.threshold_ = float(params["threshold"])
        return out

    def score(self, features: np.ndarray) -> np.ndarray:
        """P(error > miss) per row (NaN where a feature is not finite)."""
        if self.coef_ is None or self.mean_ is None or self.std_ is None:
            raise RuntimeError("ErrorScore is not fitted")
        x = np.atleast_2d(np.asarray(features, dtype=float))
        z = (x - self.mean_) / self.std_
        out = 0.5 * (1.0 + np.tanh(0.5 * (self.coef_[0] + z @ self.coef_[1:])))
        return np.where(np.isfinite(x).all(axis=1), out, np.nan)

    def warns(self, features: np.ndarray) -> np.ndarray:
        return self.above(self.score(features))

    def above(self, risk: np.ndarray) -> np.ndarray:
        """Whether each risk (a :meth:`score`) is above the warning threshold; a NaN risk (a row it cannot score)
        counts as above."""
        return ~(np.asarray(risk) <= self.threshold_)


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


@dataclass
class RowRisk:
    """The risk that a served prediction is more than ``miss`` off and the features a served model computes of a
    row to get it and its interval: how novel its feature row g is among the training pairs' (:class:`InputNovelty`),
    how large a correction it applies (|ln δ1|) and whether the bucket is at rest. The interval
    (:class:`RowInterval`) learns its width from them; the risk is the interval's (:class:`IntervalRisk`), so it
    needs no row of the calibration machines to have missed.

    Before it, the served risk was a logistic :class:`ErrorScore` on these features, the tilt load (tilt-cylinder
    force over its relief force) and an ensemble's spread, warning above the 96th percentile of every calibration
    machine's risk. With three calibration rows more than 10 % off (``statics-pl``) its coefficients stayed at the
    ridge's zero and the threshold, a quantile, warned on about 4 % of the rows of every machine whatever its
    errors: left out in turn, it warned on a median 0.5 % of a calibration machine's rows (max 9 %, 2 of 16 above
    5 %); the interval's risk at P ≥ 0.5 on a median 0 (max 0.7 %, none above 5 %) with the same AUROC for rows
    more than 10 % off (0.98; :func:`scaling.evaluation.generalisation.cross_fit_served`). Read as P ≥ 0.2 or 0.3
    it warned more on the calibration machines and caught no more misses; with the correction's size as
    ln |ln δ1| in the width (a power law rather than an exponential) it caught none of the 83 rows of the
    three-member ensemble more than 10 % off. The benchmark still judges the logistic score beside it.

    ``score`` is None where no risk could be calibrated (``unavailable`` says why); :meth:`risk` then refuses."""

    novelty: InputNovelty
    score: IntervalRisk | None
    #: why there is no risk (None when there is one)
    unavailable: str | None = None

    FEATURES: ClassVar[tuple[str, ...]] = ("ln novelty of the model's feature row", "|ln δ1| predicted",
                                           "bucket at rest (1) or moving (0)")

    @classmethod
    def features(cls, novelty: InputNovelty, g: np.ndarray, log_delta: np.ndarray, static: np.ndarray
                 ) -> np.ndarray:
        """(n, 3) features (:attr:`FEATURES`) of rows with model feature rows ``g``, predicted ln δ1 and at-rest
        flags."""
        return np.column_stack([np.log(np.maximum(novelty.score(g), 1e-12)), np.abs(np.asarray(log_delta, float)),
                                np.asarray(static, dtype=float)])

    @classmethod
    def fit(cls, train_g: np.ndarray, g: np.ndarray, log_delta: np.ndarray, static: np.ndarray,
            residual: np.ndarray, groups: np.ndarray, *, miss: float = 0.10, log_bound: float | None = None,
            seed: int = 0) -> RowRisk:
        """``train_g``: feature rows of the training pairs; the rest: calibration rows (their machine in
        ``groups``, the ln δ1 residual actual − predicted in ``residual``). ``log_bound``: the miss line in ln δ1
        units (default ln(1 + ``miss``): δ1 to the power ±1 in the force). The novelty, the interval
        (:class:`RowInterval`, its default bound) and the risk read off it."""
        novelty = InputNovelty(seed=seed).fit(train_g)
        interval = RowInterval.fit(cls.features(novelty, g, log_delta, static), residual, groups)
        return cls(novelty, IntervalRisk(interval, miss, log_bound))

    def _score(self) -> IntervalRisk:
        if self.score is None:
            raise ValueError(f"no risk was calibrated: {self.unavailable}")
        return self.score

    def risk(self, g: np.ndarray, log_delta: np.ndarray, static: np.ndarray) -> np.ndarray:
        """P(error > miss) per row.

        Raises:
            ValueError: no risk was calibrated (``score`` None).
        """
        return self._score().score(self.features(self.novelty, g, log_delta, static))

    def warns(self, g: np.ndarray, log_delta: np.ndarray, static: np.ndarray) -> np.ndarray:
        return self._score().warns(self.features(self.novelty, g, log_delta, static))

    def state(self) -> tuple[dict[str, Any], np.ndarray]:
        """(JSON-able parameters, the novelty's training rows); ``score`` None and ``unavailable`` its reason where
        no risk was calibrated."""
        params, rows = self.novelty.state()
        out = {"features": list(self.FEATURES), "novelty": params,
               "score": None if self.score is None else self.score.state()}
        if self.score is None:
            out["unavailable"] = self.unavailable
        return out, rows

    @classmethod
    def from_state(cls, params: dict[str, Any], rows: np.ndarray, interval: RowInterval | None) -> RowRisk:
        """Rebuild from :meth:`state` and the ``interval`` its risk reads (stored apart, once; None for a state
        without a risk).

        Raises:
            ValueError: the state was written for other features or another risk (a checkpoint of an older
                version), or it has a risk and no ``interval`` is given.
        """
        if list(params.get("features", [])) != list(cls.FEATURES):
            raise ValueError(f"the risk was fitted on features {params.get('features')}, this version "
                             f"computes {list(cls.FEATURES)}: rebuild the checkpoint (scaletwin zoo build)")
        score = params["score"]
        if score is not None and interval is None:
            raise ValueError("the risk is read off an interval: give the interval it was calibrated with")
        return cls(InputNovelty.from_state(params["novelty"], rows),
                   None if score is None or interval is None else IntervalRisk.from_state(score, interval),
                   None if score is not None else str(params.get("unavailable") or "no risk was calibrated"))


@dataclass
class RowInterval:
    """A per-row interval on ln δ1 that a served model can compute: ln δ1 ± q_c · w(x), with w(x) = √(s(x)² + σ0²):
    s a :class:`ResidualScale` on the served features of :meth:`RowRisk.features` (:attr:`FEATURES`: novelty of
    the feature row, |ln δ1|, bucket at rest), σ0 a width floor shared by every row (``floor`` times the
    median cross-fitted scale of the calibration rows; 0: none), and q_c, per coverage c, the bound on the
    cross-fitted calibration scores |residual| / w: c of the rows of the median calibration machine
    (``machine_share`` 0.5, :func:`machine_level_quantile`), of ``machine_share`` of them, or of an average
    machine (``machine_share`` None, :func:`group_weighted_quantile`).

    The interval widens where the served features say the model is on less familiar ground, and it is calibrated
    per machine. Which bound: chosen by leaving each calibration machine of the leave-machine-out
    layout out in turn (:func:`scaling.evaluation.generalisation.cross_fit_served`). A bound for 90 % of the
    machines (share 0.9) over-covers most new machines to protect the few whose errors are their own (a handful of
    rows far off, which no served feature of one machine predicts); the median machine's bound centres each
    machine's coverage on c. The floor σ0 (a machine-level error part every row shares) and the tilt load in the
    scale did not bring more calibration machines into 85–95 % there, and are left at none.
    """

    scale: ResidualScale
    quantiles: dict[float, float]
    machine_share: float | None
    #: σ0 in ln δ1 units (0: no floor)
    floor_: float = 0.0

    #: The served features the scale reads (:meth:`RowRisk.features`).
    FEATURES: ClassVar[tuple[str, ...]] = RowRisk.FEATURES
    #: The default bound: c of the rows of the median calibration machine.
    MACHINE_SHARE: ClassVar[float] = 0.5
    #: Coverages stored by default: those served, and 0.975 and 0.99 for the tail :meth:`exceedance` extrapolates.
    COVERAGES: ClassVar[tuple[float, ...]] = (0.5, 0.8, 0.9, 0.95, 0.975, 0.99)

    @classmethod
    def fit(cls, features: np.ndarray, residual: np.ndarray, groups: np.ndarray, *,
            coverages: Sequence[float] = COVERAGES, machine_share: float | None = MACHINE_SHARE,
            floor: float = 0.0) -> RowInterval:
        """``features``: :meth:`RowRisk.features` of the calibration rows; ``residual``: ln δ1 actual − predicted;
        ``groups``: their machines (at least two); ``machine_share``: the bound's share of machines (None: pooled);
        ``floor``: σ0 as a multiple of the median cross-fitted scale."""
        if floor < 0:
            raise ValueError(f"floor must be >= 0, got {floor}")
        x, r, g = _calibration_rows(np.asarray(features)[:, :len(cls.FEATURES)], residual, groups, "residual")
        scale = ResidualScale()
        crossed = scale.cross_fit(x, r, g)
        sigma0 = float(floor * np.median(crossed))
        scores = np.abs(r) / np.sqrt(crossed**2 + sigma0**2)
        quantiles = {float(c): calibration_bound(scores, g, float(c), machine_share) for c in coverages}
        return cls(scale, quantiles, None if machine_share is None else float(machine_share), sigma0)

    def width(self, features: np.ndarray) -> np.ndarray:
        """w(x) = √(s(x)² + σ0²) per row (ln δ1 units)."""
        s = self.scale.scale(np.asarray(features)[:, :len(self.FEATURES)])
        return np.sqrt(s**2 + self.floor_**2) if self.floor_ else s

    def half_width(self, features: np.ndarray, coverage: float) -> np.ndarray:
        """q_c · w(x) per row (ln δ1 units).

        Raises:
            ValueError: no bound stored at ``coverage``.
        """
        if float(coverage) not in self.quantiles:
            raise ValueError(f"learned-scale intervals are stored at coverage {sorted(self.quantiles)}, not {coverage}")
        return self.quantiles[float(coverage)] * self.width(features)

    def exceedance(self, features: np.ndarray, log_bound: float) -> np.ndarray:
        """P(|residual| > ``log_bound``) per row (ln δ1 units): the share of the rows of the bound's calibration
        machine (the median one by default) whose normalised residual |r| / w exceeds ``log_bound`` / w(x).

        Between the stored coverages c (bounds q_c) the share is interpolated linearly, from 1 at a bound of 0 up
        to the smallest; beyond the largest coverage c_K a power-law tail (1 − c_K)·(s / q_K)^(−a), its exponent a
        through the two largest bounds (a Pareto tail: the residuals are heavy-tailed, a machine's 90th percentile
        being 2–20 times its robust SD), so the share keeps falling, and ranking, past the calibration rows.
        NaN where the width is not finite.

        Raises:
            ValueError: fewer than two coverages stored, or ``log_bound`` not positive.
        """
        if not log_bound > 0:
            raise ValueError(f"log_bound must be > 0, got {log_bound}")
        levels = np.array(sorted(self.quantiles))
        if levels.size < 2:
            raise ValueError(f"an exceedance needs at least two stored coverages, got {levels.tolist()}")
        bounds = np.maximum.accumulate(np.array([self.quantiles[float(c)] for c in levels]))
        with np.errstate(divide="ignore", invalid="ignore"):
            s = log_bound / self.width(features)
        out = 1.0 - np.interp(s, np.r_[0.0, bounds], np.r_[0.0, levels])
        top, below = bounds[-1], bounds[-2]
        exponent = (math.log((1.0 - levels[-2]) / (1.0 - levels[-1])) / math.log(top / below)
                    if top > below > 0 else math.inf)
        tail = s > top
        with np.errstate(over="ignore"):
            out[tail] = (1.0 - levels[-1]) * (s[tail] / top) ** (-exponent)
        return np.where(np.isfinite(s), out, np.nan)

    def state(self) -> dict[str, Any]:
        """JSON-able parameters (:meth:`from_state` rebuilds the instance)."""
        return {"scale": self.scale.state(), "quantiles": {str(c): q for c, q in self.quantiles.items()},
                "machine_share": self.machine_share, "floor": self.floor_, "features": list(self.FEATURES)}

    @classmethod
    def from_state(cls, params: dict[str, Any]) -> RowInterval:
        """Rebuild from :meth:`state`.

        Raises:
            ValueError: the state was written for other features (a checkpoint of an older version).
        """
        if list(params.get("features", [])) != list(cls.FEATURES):
            raise ValueError(f"the interval's scale was fitted on features {params.get('features')}, this version "
                             f"computes {list(cls.FEATURES)}: rebuild the checkpoint (scaletwin zoo build)")
        share = params.get("machine_share")
        return cls(ResidualScale.from_state(params["scale"]),
                   {float(c): float(q) for c, q in params["quantiles"].items()},
                   None if share is None else float(share), float(params.get("floor", 0.0)))


@dataclass
class IntervalRisk:
    """The served risk, read off the served interval: P(a row's F21 is more than ``miss`` off) =
    :meth:`RowInterval.exceedance` at the miss line ``log_bound`` (ln δ1 units; None: ln(1 + ``miss``), where F21
    goes with δ1 to the power ±1), and a warning where that is at least ``warn_probability`` (one half: a miss more
    likely than not). Calibrated as the interval is, on machines held out of training, and it needs no row of
    them to have missed; a row whose width cannot be computed counts as warned."""

    interval: RowInterval
    miss: float = 0.10
    log_bound: float | None = None
    warn_probability: float = 0.5

    def __post_init__(self) -> None:
        if self.log_bound is None and self.miss > 0:
            self.log_bound = math.log1p(self.miss)
        if not (self.miss > 0 and self.log_bound is not None and self.log_bound > 0
                and 0 < self.warn_probability <= 1):
            raise ValueError(f"miss and log_bound must be > 0 and warn_probability in (0, 1], got {self.miss}, "
                             f"{self.log_bound}, {self.warn_probability}")

    def score(self, features: np.ndarray) -> np.ndarray:
        """P(error > miss) per row (NaN where a feature is not finite)."""
        assert self.log_bound is not None  # set in __post_init__
        return self.interval.exceedance(np.atleast_2d(np.asarray(features, dtype=float)), self.log_bound)

    def warns(self, features: np.ndarray) -> np.ndarray:
        return self.above(self.score(features))

    def above(self, risk: np.ndarray) -> np.ndarray:
        """Whether each risk (a :meth:`score`) is at the warning probability or above; NaN counts as above."""
        return ~(np.asarray(risk) < self.warn_probability)

    def state(self) -> dict[str, Any]:
        """JSON-able parameters, the interval's left out: it is stored once, as the interval it is
        (:meth:`from_state` rebuilds the instance from both)."""
        return {"kind": "interval", "miss": self.miss, "log_bound": self.log_bound,
                "warn_probability": self.warn_probability}

    @classmethod
    def from_state(cls, params: dict[str, Any], interval: RowInterval) -> IntervalRisk:
        """Rebuild from :meth:`state` and the ``interval`` it reads.

        Raises:
            ValueError: the state is of another kind of risk (a checkpoint of an older version).
        """
        if params.get("kind") != "interval" or "interval" in params:
            raise ValueError("the checkpoint's risk was written by an older version: rebuild the checkpoint "
                             "(scaletwin zoo build)")
        return cls(interval, float(params["miss"]), float(params["log_bound"]), float(params["warn_probability"]))
