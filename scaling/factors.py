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

All functions take raw signals in any consistent unit system: the groups are dimensionless, so δ1 and g do not
depend on the units (N, m, kg, s or mm, g, ms).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from fractions import Fraction
from typing import Any, Literal

import numpy as np
import pandas as pd

from scaling.groups import PiGroup

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


def _source_values(source_row: Rows, groups: Sequence[PiGroup]) -> np.ndarray:
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
    src = _source_values(source_row, groups)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = src[None, :] / group_values(target_rows, groups)
    return _check(d, "distortion factors", nonfinite)


def prediction_factor(source_row: Rows, target_rows: Rows, output_group: PiGroup, *,
                      nonfinite: NonFinite = "raise") -> np.ndarray:
    """Prediction factor ``δ1 = π_1(source) / π_1(target)`` (Eq. 16, 20), shape ``(n_targets,)``."""
    src = _source_values(source_row, [output_group])[0]
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
    pi1_src = _source_values(source_row, [output_group])[0]
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


# --------------------------------------------------------------------------------------------------------------------
# the δ1 data set
# --------------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class DeltaDataset:
    """Pairs (source row, target row) with their group values and, when known, δ1 = π_1(source)/π_1(target).

    Arrays have one entry per pair (``n``); group arrays have shape ``(n, k)`` for the k input groups.
    ``sequence_keys()`` gives one time-ordered sequence per (reference, machine, episode) for recurrent models.

    Attributes:
        output_group, input_groups: π_1 and π_2..π_n.
        pi_source, pi_target: input group values of the source (reference) and target rows.
        pi1_source: π_1 of the source row; ``pi1_target``: π_1 of the target row (``None`` if unknown).
        rest_target: π_1 of the target without the scaled variable (to recover it from δ1, Eq. 22).
        machine, episode, t, reference: target machine, dig-cycle id, time (s) and id of the source row.
        target_variable: the variable of π_1 recovered by :meth:`recover`.
        dropped: number of recording rows dropped per reason (non-finite group, non-positive δ1, ...).
    """

    output_group: PiGroup
    input_groups: tuple[PiGroup, ...]
    pi_source: np.ndarray
    pi_target: np.ndarray
    pi1_source: np.ndarray
    pi1_target: np.ndarray | None
    rest_target: np.ndarray
    machine: np.ndarray
    episode: np.ndarray
    t: np.ndarray
    reference: np.ndarray
    target_variable: str
    dropped: Mapping[str, int] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.pi1_source.shape[0])

    @property
    def labelled(self) -> bool:
        return self.pi1_target is not None

    @property
    def delta(self) -> np.ndarray:
        """δ1 = π_1(source)/π_1(target) (Eq. 20)."""
        if self.pi1_target is None:
            raise ValueError("this DeltaDataset has no target π_1 (unlabelled); δ1 is unknown")
        return self.pi1_source / self.pi1_target

    @property
    def log_delta(self) -> np.ndarray:
        return np.log(self.delta)

    def distortions(self) -> np.ndarray:
        """Raw d_n = π_n^s/π_n^t, shape ``(n, k)``; may hold inf where a target group vanishes (explicit request)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.pi_source / self.pi_target

    def episode_keys(self) -> np.ndarray:
        """``"machine/episode"`` per pair: the unit of train/test splitting."""
        return np.char.add(np.char.add(self.machine.astype(str), "/"), self.episode.astype(str))

    def sequence_keys(self) -> np.ndarray:
        """``"reference|machine/episode"`` per pair: one time series per key."""
        return np.char.add(np.char.add(self.reference.astype(str), "|"), self.episode_keys())

    def sequences(self) -> list[np.ndarray]:
        """Index arrays, one per sequence key, each sorted by time (stable)."""
        keys = self.sequence_keys()
        order = np.lexsort((self.t, keys))
        _, starts = np.unique(keys[order], return_index=True)
        return [order[a:b] for a, b in zip(starts, [*starts[1:], len(order)], strict=True)]

    def subset(self, index: np.ndarray) -> DeltaDataset:
        """Pairs selected by an integer index or boolean mask."""
        idx = np.asarray(index)
        arrays = {name: getattr(self, name)[idx] for name in _PAIR_FIELDS if getattr(self, name) is not None}
        return replace(self, **arrays)

    def split_by_episode(self, test_fraction: float = 0.2, seed: int = 0) -> tuple[DeltaDataset, DeltaDataset]:
        """(train, test) with whole episodes on one side only (no time-series leakage between them).

        At least one episode goes to each side when there are two or more; each machine is split separately so
        both sides see every machine when it has two or more episodes.
        """
        if not 0 < test_fraction < 1:
            raise ValueError(f"test_fraction must be in (0, 1), got {test_fraction}")
        keys = self.episode_keys()
        rng = np.random.default_rng(seed)
        machines = self.machine.astype(str)
        per_machine = [np.unique(keys[machines == m]) for m in np.unique(machines)]
        if not any(len(k) > 1 for k in per_machine):  # one episode per machine: split across machines instead
            per_machine = [np.unique(keys)]
        test_keys: list[str] = []
        for eps_m in per_machine:
            n_test = min(len(eps_m) - 1, max(1, round(test_fraction * len(eps_m)))) if len(eps_m) > 1 else 0
            test_keys.extend(rng.permutation(eps_m)[:n_test].tolist())
        if not test_keys:
            raise ValueError("need at least two episodes to split by episode")
        is_test = np.isin(keys, test_keys)
        return self.subset(~is_test), self.subset(is_test)

    def recover(self, delta: np.ndarray | float) -> np.ndarray:
        """Target value of the scaled variable from δ1 (Eq. 22): ``v = (π_1(source)/δ1 / R_target)^(1/e)``."""
        _, exp = scaled_variable(self.output_group, self.target_variable)
        return solve_variable(pi1_to_target(self.pi1_source, delta), self.rest_target, exp)

    def target_values(self) -> np.ndarray:
        """Actual target value of the scaled variable (from the labels)."""
        if self.pi1_target is None:
            raise ValueError("unlabelled DeltaDataset")
        _, exp = scaled_variable(self.output_group, self.target_variable)
        return solve_variable(self.pi1_target, self.rest_target, exp)

    def groups_dict(self) -> dict[str, Any]:
        return {"output": self.output_group.to_dict(), "inputs": [g.to_dict() for g in self.input_groups],
                "target_variable": self.target_variable}

    # ---------------------------------------------------------------------------------------------- builders

    @classmethod
    def from_recordings(cls, recordings: pd.DataFrame, output_group: PiGroup, input_groups: Sequence[PiGroup], *,
                        source_machine: str = "er12", target_machines: Sequence[str] | None = None,
                        n_references: int = 1, seed: int = 0, reference_index: Sequence[Any] | None = None,
                        target_variable: str | None = None, warn: bool = True) -> DeltaDataset:
        """Build pairs as the paper does: reference row(s) of the source twin × every target row.

        Args:
            recordings: one row per control step with ``machine``, ``episode``, ``t`` and the raw signals.
            source_machine: machine of the calibrated twin (paper: model), e.g. ``"er12"``.
            target_machines: machines whose rows are targets (default: every machine, the source included).
            n_references: number of reference rows drawn (seeded) from the source machine; > 1 augments the data.
            reference_index: explicit index labels of the reference rows (overrides the draw).
            target_variable: variable of π_1 to recover (default: the one with exponent +1, e.g. F21).
            warn: emit a :class:`NonFiniteRowsWarning` when rows are dropped (counts are always in ``dropped``).

        Rows whose groups are non-finite, or whose δ1 would be non-finite or ≤ 0, are dropped and counted.
        """
        _require_columns(recordings, ["machine", "episode", "t"])
        if not recordings.index.is_unique:
            raise ValueError("recordings need a unique index (reference rows are addressed by index label)")
        var, _ = scaled_variable(output_group, target_variable)
        rec, dropped = _finite_rows(recordings, output_group, tuple(input_groups))
        refs = _pick_references(rec, source_machine, n_references, seed, reference_index)
        targets = rec if target_machines is None else rec[rec["machine"].astype(str).isin(list(target_machines))]
        parts = [cls.from_pairs(rec.loc[r], targets, output_group, input_groups, target_variable=var,
                                reference_id=i, warn=False) for i, r in enumerate(refs)]
        ds = concat_datasets(parts)
        for k, v in ds.dropped.items():
            dropped[k] = dropped.get(k, 0) + v
        if warn and any(dropped.values()):
            warnings.warn(f"DeltaDataset dropped rows: {dropped}", NonFiniteRowsWarning, stacklevel=2)
        return replace(ds, dropped=dropped)

    @classmethod
    def from_pairs(cls, source_row: Rows, target_rows: pd.DataFrame, output_group: PiGroup,
                   input_groups: Sequence[PiGroup], *, target_variable: str | None = None, reference_id: int = 0,
                   warn: bool = True) -> DeltaDataset:
        """Pairs of one source row with every target row. Targets without the scaled variable give an unlabelled
        set (for prediction); otherwise target rows with a non-finite group or δ1 ≤ 0 are dropped and counted."""
        var, _ = scaled_variable(output_group, target_variable)
        groups = tuple(input_groups)
        src = _source_values(source_row, groups)
        pi1_src = float(_source_values(source_row, [output_group])[0])
        if not (np.all(np.isfinite(src)) and np.isfinite(pi1_src) and pi1_src > 0):
            raise ValueError(f"the source row needs finite groups and π_1 > 0; got π = {src}, π_1 = {pi1_src}")
        tgt = target_rows.reset_index(drop=True)
        pi_t = group_values(tgt, groups)
        rest = rest_of_group(tgt, output_group, var)
        pi1_t = output_group.evaluate(tgt).reshape(-1) if var in tgt.columns else None
        keep, dropped = _valid_mask(pi_t, rest, pi1_t)
        if warn and any(dropped.values()):
            warnings.warn(f"DeltaDataset dropped rows: {dropped}", NonFiniteRowsWarning, stacklevel=2)
        n = int(keep.sum())
        return cls(output_group=output_group, input_groups=groups, pi_source=np.tile(src, (n, 1)),
                   pi_target=pi_t[keep], pi1_source=np.full(n, pi1_src),
                   pi1_target=None if pi1_t is None else pi1_t[keep], rest_target=rest[keep],
                   machine=_column(tgt, "machine", keep, "target").astype(str),
                   episode=_column(tgt, "episode", keep, 0).astype(np.int64),
                   t=_column(tgt, "t", keep, 0.0).astype(float), reference=np.full(n, reference_id, dtype=np.int64),
                   target_variable=var, dropped=dropped)


_PAIR_FIELDS = ("pi_source", "pi_target", "pi1_source", "pi1_target", "rest_target", "machine", "episode", "t",
                "reference")


def concat_datasets(parts: Sequence[DeltaDataset]) -> DeltaDataset:
    """Stack data sets built with the same groups (counts in ``dropped`` are summed)."""
    if not parts:
        raise ValueError("nothing to concatenate")
    first = parts[0]
    if any(p.groups_dict() != first.groups_dict() for p in parts):
        raise ValueError("cannot concatenate DeltaDatasets built with different groups")
    labelled = all(p.labelled for p in parts)
    arrays = {name: np.concatenate([getattr(p, name) for p in parts]) if labelled or name != "pi1_target" else None
              for name in _PAIR_FIELDS}
    dropped: dict[str, int] = {}
    for p in parts:
        for k, v in p.dropped.items():
            dropped[k] = dropped.get(k, 0) + v
    return replace(first, **arrays, dropped=dropped)


def _column(frame: pd.DataFrame, name: str, keep: np.ndarray, default: Any) -> np.ndarray:
    return np.asarray(frame[name])[keep] if name in frame.columns else np.full(int(keep.sum()), default)


def _require_columns(df: pd.DataFrame, cols: Sequence[str]) -> None:
    missing = [c for c in cols if c not in df.columns]
    if missing:
        raise KeyError(f"recordings lack columns {missing}")


def _valid_mask(pi_t: np.ndarray, rest: np.ndarray, pi1_t: np.ndarray | None) -> tuple[np.ndarray, dict[str, int]]:
    keep = np.ones(pi_t.shape[0], dtype=bool)
    dropped: dict[str, int] = {}

    def drop(reason: str, bad: np.ndarray) -> None:
        nonlocal keep
        n_bad = int(np.sum(bad & keep))
        if n_bad:
            dropped[reason] = dropped.get(reason, 0) + n_bad
        keep = keep & ~bad

    drop("non-finite input group", ~np.all(np.isfinite(pi_t), axis=1))
    drop("non-finite or zero rest of π1", ~np.isfinite(rest) | (rest == 0))
    if pi1_t is not None:
        drop("non-finite π1", ~np.isfinite(pi1_t))
        drop("π1 ≤ 0 (δ1 not positive)", ~(pi1_t > 0))
    return keep, dropped


def _finite_rows(rec: pd.DataFrame, output_group: PiGroup,
                 groups: tuple[PiGroup, ...]) -> tuple[pd.DataFrame, dict[str, int]]:
    pi_t = group_values(rec, groups)
    pi1 = output_group.evaluate(rec).reshape(-1)
    keep, dropped = _valid_mask(pi_t, np.ones(len(rec)), pi1)
    return rec.loc[keep], dropped


def _pick_references(rec: pd.DataFrame, source_machine: str, n_references: int, seed: int,
                     reference_index: Sequence[Any] | None) -> list[Any]:
    if reference_index is not None:
        missing = [r for r in reference_index if r not in rec.index]
        if missing:
            raise KeyError(f"reference rows {missing} are not among the valid recording rows")
        return list(reference_index)
    pool = rec.index[rec["machine"].astype(str) == source_machine]
    if len(pool) < n_references or n_references < 1:
        raise ValueError(f"need {n_references} valid rows of source machine {source_machine!r}; have {len(pool)}")
    rng = np.random.default_rng(seed)
    return list(pool[np.sort(rng.choice(len(pool), size=n_references, replace=False))])
