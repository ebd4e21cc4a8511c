"""The δ1 learning data set: (source row, target row) pairs with their group values and prediction factor.

Built from recordings as in the paper (reference row(s) of the calibrated source twin × every target row) or from
explicit pairs; see :mod:`scaling.dimensions.factors` for the δ1 convention and the feature transform.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pandas as pd

from scaling.dimensions.factors import (
    NonFiniteRowsWarning,
    Rows,
    group_values,
    pi1_to_target,
    rest_of_group,
    scaled_variable,
    solve_variable,
    source_values,
)
from scaling.dimensions.groups import PiGroup


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
        src = source_values(source_row, groups)
        pi1_src = float(source_values(source_row, [output_group])[0])
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


    @classmethod
    def from_matched(cls, source_rows: pd.DataFrame, target_rows: pd.DataFrame, output_group: PiGroup,
                     input_groups: Sequence[PiGroup], *, target_variable: str | None = None,
                     reference_id: int = 0) -> DeltaDataset:
        """Row-aligned pairs: ``source_rows.iloc[i]`` is the source of ``target_rows.iloc[i]`` (e.g. its matched
        row of another machine, :func:`scaling.data.product_line.match_rows`). Pairs with a non-finite group, a source
        π_1 ≤ 0 or (labelled targets) δ1 ≤ 0 are dropped and counted in ``dropped``."""
        if len(source_rows) != len(target_rows):
            raise ValueError(f"source and target rows must align: {len(source_rows)} != {len(target_rows)}")
        var, _ = scaled_variable(output_group, target_variable)
        groups = tuple(input_groups)
        src, tgt = source_rows.reset_index(drop=True), target_rows.reset_index(drop=True)
        pi_s, pi_t = group_values(src, groups), group_values(tgt, groups)
        pi1_s = output_group.evaluate(src).reshape(-1)
        pi1_t = output_group.evaluate(tgt).reshape(-1) if var in tgt.columns else None
        keep, dropped = _valid_mask(pi_t, rest_of_group(tgt, output_group, var), pi1_t)
        bad_source = ~(np.all(np.isfinite(pi_s), axis=1) & np.isfinite(pi1_s) & (pi1_s > 0))
        if n_bad := int(np.sum(bad_source & keep)):
            dropped["source row not finite or π1 ≤ 0"] = n_bad
        keep &= ~bad_source
        rest = rest_of_group(tgt, output_group, var)
        return cls(output_group=output_group, input_groups=groups, pi_source=pi_s[keep], pi_target=pi_t[keep],
                   pi1_source=pi1_s[keep], pi1_target=None if pi1_t is None else pi1_t[keep], rest_target=rest[keep],
                   machine=_column(tgt, "machine", keep, "target").astype(str),
                   episode=_column(tgt, "episode", keep, 0).astype(np.int64),
                   t=_column(tgt, "t", keep, 0.0).astype(float),
                   reference=np.full(int(keep.sum()), reference_id, dtype=np.int64), target_variable=var,
                   dropped=dropped)

    def split_by_machine(self, test_machines: Sequence[str]) -> tuple[DeltaDataset, DeltaDataset]:
        """(train, test): pairs whose *target* machine is in ``test_machines`` go to test (grouped split)."""
        is_test = np.isin(self.machine.astype(str), [str(m) for m in test_machines])
        return self.subset(~is_test), self.subset(is_test)


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
