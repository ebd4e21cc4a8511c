"""Distortion factors, the prediction factor δ1 and the δ1 learning data set.

Convention (the paper's, used everywhere in :mod:`scaling`)
------------------------------------------------------------
* **source** = the calibrated machine whose twin is trusted (the paper's "model", superscript *m*),
  e.g. one row of the ER12 twin;
* **target** = the machine to predict (the paper's "prototype", superscript *p*), e.g. a WA475 row or the miniature.

With groups π_1 (output, holds the scaled variable, e.g. ``F21/F31``) and π_2..π_n (inputs):

* distortion factor        ``d_n = π_n(source) / π_n(target)``                         (Eq. 18)
* prediction factor        ``δ1 = π_1(source) / π_1(target)``                           (Eq. 16, 20)
* prediction               ``π_1(target) = π_1(source) / δ1`` and, for π_1 = v·R with the
  scaled variable v at exponent e and R the rest of the group, ``v_target = (π_1(target)/R_target)^(1/e)``;
  for π_1 = F21/F31 this is ``F21_target = F31_target · π_1(source) / δ1``                 (Eq. 22)

Note that this δ1 is the *inverse* of the textbook prediction factor (π_p = δ·π_m).

Learnt quantity and features
----------------------------
Models learn ``ln δ1 = f(g_2, ..., g_n)``. Raw distortions divide by zero when a group vanishes (a1 and α1 are zero
at rest, so d_n = ∞ for a static target), so the features are the *generalised log distortions*

    ``g_n = s_n · [asinh(π_n^s / (2 ε_n)) − asinh(π_n^t / (2 ε_n))]``

with ε_n > 0 a small per-group scale and s_n ∈ {+1, −1} a per-group orientation, both fixed from training data by
:class:`LogDistortion` and stored with the model. When π^s and π^t share the sign s_n and |π| ≫ ε_n,
``g_n = ln d_n`` (to O(ε²/π²)), so a power law δ1 = ∏ d_n^{a_n} is linear in g. g stays finite at π = 0
(a static target) and for groups of mixed sign (signed cylinder forces, negative COM coordinates), where ln d_n
is undefined; asinh is odd, so a group that is negative in both rows gives −ln d_n before orientation and
+ln d_n after it.

The learning data set of (source, target) pairs, built on these functions, is
:class:`scaling.data.delta_dataset.DeltaDataset`.

All functions take raw signals in any consistent unit system: the groups are dimensionless, so δ1 and g do not
depend on the units (N, m, kg, s or mm, g, ms).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction
from typing import Any, Literal

import numpy as np
import pandas as pd

from scaling.dimensions.groups import PiGroup

Rows = pd.DataFrame | Mapping[str, Any]
NonFinite = Literal["raise", "keep"]


class NonFiniteRowsWarning(UserWarning):
    """Rows were dropped because a group, or δ1, was not finite (or δ1 was not positive)."""


# --------------------------------------------------------------------------------------------------------------------
# group values and raw factors
# --------------------------------------------------------------------------------------------------------------------


def group_values(rows: Rows, groups: Sequence[PiGroup]) -> np.ndarray:
    """Values of ``groups`` on ``rows`` as an array of shape ``(n_rows, n_groups)`` (one row gives ``(1, k)``)."""
    cols = [np.atleast_1d(g.evaluate(rows)) for g in groups]
    return np.column_stack(cols) if cols else np.zeros((len(_as_frame(rows)), 0))


def _as_frame(rows: Rows) -> pd.DataFrame:
    if isinstance(rows, pd.DataFrame):
        return rows
    if isinstance(rows, pd.Series):
        return rows.to_frame().T
    return pd.DataFrame({k: np.atleast_1d(v) for k, v in rows.items()})


def source_values(source_row: Rows, groups: Sequence[PiGroup]) -> np.ndarray:
    vals = group_values(source_row, groups)
    if vals.shape[0] != 1:
        raise ValueError(f"source_row must be a single row; got {vals.shape[0]} rows")
    return vals[0]


def _check(values: np.ndarray, what: str, nonfinite: NonFinite) -> np.ndarray:
    if nonfinite == "raise" and not np.all(np.isfinite(values)):
        bad = int(np.sum(~np.isfinite(values)))
        raise ValueError(f"{bad} non-finite {what}; a group vanishes in the target (d_n = π^s/0). "
                         "Use LogDistortion features, or nonfinite='keep' to get inf/NaN explicitly.")
    return values


def distortions(source_row: Rows, target_rows: Rows, groups: Sequence[PiGroup], *,
                nonfinite: NonFinite = "raise") -> np.ndarray:
    """Distortion factors ``d_n = π_n(source) / π_n(target)`` (Eq. 18), shape ``(n_targets, n_groups)``.

    Args:
        source_row: one row of raw signals of the calibrated machine (paper: model).
        target_rows: rows of raw signals of the machine to predict (paper: prototype).
        groups: the input groups π_2..π_n.
        nonfinite: ``"raise"`` (default) on any inf/NaN (e.g. a1 = 0 in the target), ``"keep"`` to return them.
    """
    src = source_values(source_row, groups)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = src[None, :] / group_values(target_rows, groups)
    return _check(d, "distortion factors", nonfinite)


def prediction_factor(source_row: Rows, target_rows: Rows, output_group: PiGroup, *,
                      nonfinite: NonFinite = "raise") -> np.ndarray:
    """Prediction factor ``δ1 = π_1(source) / π_1(target)`` (Eq. 16, 20), shape ``(n_targets,)``."""
    src = source_values(source_row, [output_group])[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = src / output_group.evaluate(target_rows).reshape(-1)
    return _check(delta, "prediction factors", nonfinite)


def pi1_to_target(pi1_source: np.ndarray | float, delta: np.ndarray | float) -> np.ndarray:
    """``π_1(target) = π_1(source) / δ1`` (Eq. 16 solved for the target / paper's prototype)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(pi1_source, dtype=float) / np.asarray(delta, dtype=float)


def pi1_to_source(pi1_target: np.ndarray | float, delta: np.ndarray | float) -> np.ndarray:
    """``π_1(source) = δ1 · π_1(target)`` (Eq. 16); the inverse of :func:`pi1_to_target`."""
    return np.asarray(delta, dtype=float) * np.asarray(pi1_target, dtype=float)


def scaled_variable(output_group: PiGroup, variable: str | None = None) -> tuple[str, Fraction]:
    """The variable of π_1 to recover and its exponent; by default the unique variable with exponent +1."""
    if variable is None:
        ones = [k for k, e in output_group.exponents.items() if e == 1]
        if len(ones) != 1:
            raise ValueError(f"cannot pick the scaled variable of {output_group.expression()}: "
                             f"{len(ones)} variables have exponent 1; pass variable=...")
        variable = ones[0]
    if variable not in output_group.exponents:
        raise ValueError(f"{variable!r} is not a variable of {output_group.expression()}")
    return variable, output_group.exponents[variable]


def rest_of_group(rows: Rows, output_group: PiGroup, variable: str) -> np.ndarray:
    """π_1 without the scaled variable: ``R = ∏_{v ≠ variable} v^e`` on ``rows`` (needs no value of ``variable``)."""
    others = {k: e for k, e in output_group.exponents.items() if k != variable}
    if not others:
        return np.ones(len(_as_frame(rows)))
    return PiGroup(others).evaluate(rows).reshape(-1)


def solve_variable(pi1: np.ndarray, rest: np.ndarray, exponent: Fraction) -> np.ndarray:
    """``v = (π_1 / R)^(1/e)`` from ``π_1 = v^e · R``; exact division when e = 1."""
    with np.errstate(divide="ignore", invalid="ignore"):
        base = np.asarray(pi1, dtype=float) / np.asarray(rest, dtype=float)
        return base if exponent == 1 else np.power(base, 1.0 / float(exponent))


def recover_target(source_row: Rows, target_rows: Rows, output_group: PiGroup, delta: np.ndarray | float, *,
                   variable: str | None = None) -> np.ndarray:
    """Target value of the scaled variable from δ1 (Eq. 22 generalised), shape ``(n_targets,)``.

    ``π_1(target) = π_1(source)/δ1`` then ``v = (π_1(target)/R_target)^(1/e)``; for π_1 = F21/F31 this is
    ``F21_target = F31_target · π_1(source) / δ1``. ``target_rows`` need not contain ``variable``.

    Raises:
        ValueError: the result is not finite (e.g. δ1 = 0 or F31_target = 0).
    """
    var, exp = scaled_variable(output_group, variable)
    pi1_src = source_values(source_row, [output_group])[0]
    pi1_tgt = pi1_to_target(pi1_src, delta)
    value = solve_variable(pi1_tgt, rest_of_group(target_rows, output_group, var), exp)
    return _check(np.atleast_1d(value), f"recovered {var}", "raise")


# --------------------------------------------------------------------------------------------------------------------
# generalised log distortion features
# --------------------------------------------------------------------------------------------------------------------


@dataclass
class LogDistortion:
    """Finite feature transform ``g_n = s_n·[asinh(π^s/2ε_n) − asinh(π^t/2ε_n)]`` (≈ ln d_n for |π| ≫ ε_n).

    Attributes:
        rel_eps: ε_n = rel_eps × median(|π_n|) over the non-zero finite training values (1.0 if there are none).
        include_source: also return the source's own ``s_n·asinh(π^s/2ε_n)`` (needed when several reference rows
            are stacked, since δ1 then depends on the reference as well as on the distortions).
        eps, sign: fitted per-group ε_n (> 0) and orientation s_n (sign of the median training value; +1 at 0).
    """

    rel_eps: float = 1e-3
    include_source: bool = False
    eps: np.ndarray | None = None
    sign: np.ndarray | None = None

    def fit(self, pi_values: np.ndarray) -> LogDistortion:
        """Fix ε_n and s_n from group values of shape ``(n_rows, n_groups)``; non-finite values are ignored."""
        if self.rel_eps <= 0:
            raise ValueError(f"rel_eps must be > 0, got {self.rel_eps}")
        vals = np.asarray(pi_values, dtype=float)
        eps, sign = np.ones(vals.shape[1]), np.ones(vals.shape[1])
        for j in range(vals.shape[1]):
            col = vals[np.isfinite(vals[:, j]), j]
            nz = np.abs(col[col != 0])
            if nz.size:
                eps[j] = self.rel_eps * float(np.median(nz))
            if col.size and np.median(col) < 0:
                sign[j] = -1.0
        self.eps, self.sign = eps, sign
        return self

    @property
    def fitted(self) -> bool:
        return self.eps is not None and self.sign is not None

    def _h(self, pi: np.ndarray) -> np.ndarray:
        if not self.fitted:
            raise RuntimeError("LogDistortion is not fitted; call fit(pi_values) first")
        return self.sign * np.arcsinh(np.asarray(pi, dtype=float) / (2.0 * self.eps))

    def transform(self, pi_source: np.ndarray, pi_target: np.ndarray) -> np.ndarray:
        """Features from source values (``(k,)`` or ``(n, k)``) and target values ``(n, k)``; shape ``(n, k)``
        or ``(n, 2k)`` with ``include_source``."""
        hs = np.broadcast_to(self._h(pi_source), np.shape(pi_target))
        g = hs - self._h(pi_target)
        return np.hstack([g, hs]) if self.include_source else g

    def n_features(self, n_groups: int) -> int:
        return 2 * n_groups if self.include_source else n_groups

    def to_dict(self) -> dict[str, Any]:
        return {"rel_eps": self.rel_eps, "include_source": self.include_source,
                "eps": None if self.eps is None else [float(x) for x in self.eps],
                "sign": None if self.sign is None else [float(x) for x in self.sign]}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> LogDistortion:
        eps, sign = d.get("eps"), d.get("sign")
        return cls(rel_eps=float(d["rel_eps"]), include_source=bool(d.get("include_source", False)),
                   eps=None if eps is None else np.asarray(eps, dtype=float),
                   sign=None if sign is None else np.asarray(sign, dtype=float))

