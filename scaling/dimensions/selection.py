"""Scoring and ranking candidate pi-group sets against data, with a shuffled-data baseline.

The paper's filter (:class:`~scaling.dimensions.scorers.PearsonRMS`): for a set, the score is the root mean square, over
the non-target groups, of the Pearson correlation between the target group ``pi1`` and that group. Alternatives share
one interface, :meth:`~scaling.dimensions.scorers.Scorer.score`, and are selected by name
(:data:`~scaling.dimensions.scorers.SCORERS`) or passed as objects. Per-group scorers (Pearson, Spearman,
``MutualInformation(joint=False)``) reward sets whose groups each track ``pi1``; joint scorers (``MutualInformation()``,
:class:`~scaling.dimensions.scorers.CrossValidatedR2`) measure how well the groups *together* determine ``pi1``.
Note that all complete sets of one problem span the same groups (Buckingham), so a joint score differs between
them only through noise and the spread of ``pi1``; it is most useful to compare different variable lists.

Shuffled baseline: every raw *variable* is permuted across rows independently (one permutation per variable, the
same shuffled datasets for all sets), then all groups are recomputed and scored. This removes every physical
relation but keeps the algebraic one: ratios that share a variable (``F21/F31`` and ``m_b*a1/F31`` both contain
``F31``) stay correlated after the shuffle, so that spurious part shows up in ``baseline_mean``. (Shuffling the
target group against the other groups would drive every baseline to ~0 and hide the shared-variable artefact.)
Ranking is by ``score`` (the paper) unless asked otherwise; ``excess = score - baseline_mean`` and
``z = excess / baseline_std`` are the diagnostics: a winner with a small ``z`` is indistinguishable from the
artefact. (Ranking *by* excess is offered but penalises sets whose groups share variables even when the relation
is real, because the baseline is the artefact under independence, not a part of the observed score.)

Rows: a row where the target or a group is non-finite (zero to a negative power, negative base to a fractional
power, ...) or outside a scorer's domain (e.g. ``log`` of 0) is dropped per set and counted in ``n_dropped``. A set
left with fewer rows than the scorer needs gets a NaN score *and* a ``note`` saying why, and is ranked last.
Data must be in one coherent unit system (SI, or mm-g-ms, ...); convert mixed units first, e.g. with
:func:`scaling.dimensions.units.conversion_factor`.

The scorers themselves live in :mod:`scaling.dimensions.scorers`.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from typing import Literal

import numpy as np
import pandas as pd

from scaling.dimensions.groups import PiGroup
from scaling.dimensions.pi_theorem import PiSet
from scaling.dimensions.scorers import Scorer, get_scorer

__all__ = ["DataLike", "RankBy", "as_columns", "rank_pi_sets", "select_pi_set"]

DataLike = Mapping[str, np.ndarray] | pd.DataFrame
RankBy = Literal["score", "excess", "z"]


def as_columns(data: DataLike, names: Sequence[str]) -> dict[str, np.ndarray]:
    """The named raw variables of ``data`` as equal-length 1-D float arrays.

    Raises:
        ValueError: a variable is missing or the columns differ in length.
    """
    missing = [n for n in names if n not in data]
    if missing:
        raise ValueError(f"data lacks variables {missing}; has {sorted(map(str, data.keys()))}")
    cols = {n: np.asarray(data[n], dtype=float).ravel() for n in names}
    lengths = {n: len(c) for n, c in cols.items()}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"data columns differ in length: {lengths}")
    return cols


def rank_pi_sets(sets: Sequence[PiSet], data: DataLike, scorer: str | Scorer = "pearson", n_shuffles: int = 20, *,
                 seed: int = 0, rank_by: RankBy = "score",
                 reference: Literal["group", "variable"] = "group") -> pd.DataFrame:
    """Score every set on ``data`` and against the shuffled baseline (module docstring); best first.

    Args:
        sets: candidate sets sharing one target (e.g. from :func:`scaling.dimensions.pi_theorem.enumerate_pi_sets`).
        data: raw variables by name, any consistent units (groups are dimensionless).
        scorer: a :class:`~scaling.dimensions.scorers.Scorer` or a name in :data:`~scaling.dimensions.scorers.SCORERS`
        (``"pearson"`` is
            the paper's filter).
        n_shuffles: shuffled datasets for the baseline; 0 (no baseline) or >= 2.
        seed: seeds the permutations, so rankings are reproducible.
        rank_by: ``"score"`` (the paper; default), ``"excess"`` (score minus baseline mean) or ``"z"``. Ties
            (values equal to 10 decimals) keep the input order, so unit changes cannot reorder them.
        reference: ``"group"`` correlates the target group ``pi1`` with the others (default); ``"variable"``
            uses the raw target variable instead, as the paper's text words it.

    Returns:
        One row per set: ``rank, set_id`` (position in ``sets``), ``origin, description, groups, score,
        baseline_mean, baseline_std, excess, z, n_used, n_dropped, note``; unscorable sets last with a ``note``.
    """
    if not sets:
        raise ValueError("rank_pi_sets needs at least one PiSet")
    if len({s.target for s in sets}) != 1:
        raise ValueError(f"all sets must share one target, got {sorted({s.target for s in sets})}")
    if n_shuffles == 1 or n_shuffles < 0:
        raise ValueError(f"n_shuffles must be 0 or >= 2 (a baseline needs a spread), got {n_shuffles}")
    if rank_by not in ("score", "excess", "z") or (rank_by != "score" and n_shuffles == 0):
        raise ValueError(f"rank_by={rank_by!r} needs 'score', or 'excess'/'z' with n_shuffles >= 2")
    if reference not in ("group", "variable"):
        raise ValueError(f"reference must be 'group' or 'variable', got {reference!r}")
    scorer_obj = get_scorer(scorer)
    names = sorted({v for s in sets for g in s.groups for v in g.exponents} | {sets[0].target})
    cols = as_columns(data, names)
    rng = np.random.default_rng(seed)
    datasets = [cols] + [{n: c[rng.permutation(len(c))] for n, c in cols.items()} for _ in range(n_shuffles)]
    caches: list[dict] = [{} for _ in datasets]
    rows = [_row(i, s, scorer_obj, datasets, caches, reference) for i, s in enumerate(sets)]
    table = pd.DataFrame(rows)
    order = np.lexsort((table["set_id"], -np.round(table[rank_by].to_numpy(float), 10)))
    table = table.iloc[order].reset_index(drop=True)  # lexsort puts NaN keys last
    table.insert(0, "rank", np.arange(1, len(table) + 1))
    table.attrs.update(scorer=scorer_obj.name, rank_by=rank_by, n_shuffles=n_shuffles, seed=seed, reference=reference)
    return table


def select_pi_set(sets: Sequence[PiSet], data: DataLike, scorer: str | Scorer = "pearson", n_shuffles: int = 20, *,
                  seed: int = 0, rank_by: RankBy = "score", reference: Literal["group", "variable"] = "group",
                  min_z: float = 2.0) -> PiSet:
    """The best set of :func:`rank_pi_sets` (same arguments).

    Warns when the winner's ``z`` (score above the shuffled baseline, in baseline standard deviations) is below
    ``min_z``: its correlation may be the shared-variable artefact.

    Raises:
        ValueError: no set could be scored (every one lacks usable rows).
    """
    table = rank_pi_sets(sets, data, scorer, n_shuffles, seed=seed, rank_by=rank_by, reference=reference)
    best = table.iloc[0]
    if np.isnan(best[rank_by]):
        raise ValueError(f"no set could be scored: {best['note']}")
    if n_shuffles and not best["z"] >= min_z:
        warnings.warn(f"selected set {best['groups']} scores {best['score']:.3g}, only z={best['z']:.3g} baseline "
                      f"std above the shuffled baseline {best['baseline_mean']:.3g}", stacklevel=2)
    return sets[int(best["set_id"])]


def _row(index: int, pi_set: PiSet, scorer: Scorer, datasets: list[dict[str, np.ndarray]], caches: list[dict],
         reference: str) -> dict[str, object]:
    score, used, dropped, note = _score(scorer, *_values(pi_set, datasets[0], caches[0], reference))
    baseline = np.array([_score(scorer, *_values(pi_set, d, c, reference))[0]
                         for d, c in zip(datasets[1:], caches[1:], strict=True)])
    mean, std, excess, z = np.nan, np.nan, np.nan, np.nan
    valid = baseline[~np.isnan(baseline)]
    if len(valid) >= 2:
        mean, std = float(valid.mean()), float(valid.std(ddof=1))
        excess = score - mean
        z = excess / std if std > 0 else (0.0 if excess == 0 else float(np.copysign(np.inf, excess)))
    elif len(datasets) > 1:
        note = (note + "; " if note else "") + f"baseline: only {len(valid)} shuffles scorable"
    return {"set_id": index, "origin": pi_set.origin, "description": pi_set.description,
            "groups": "; ".join(pi_set.expressions()), "score": score, "baseline_mean": mean, "baseline_std": std,
            "excess": excess, "z": z, "n_used": used, "n_dropped": dropped, "note": note}


def _values(pi_set: PiSet, cols: Mapping[str, np.ndarray], cache: dict, reference: str) -> tuple[np.ndarray, ...]:
    """Target values and the (n, k-1) matrix of the other groups; group values are cached per dataset."""

    def group(g: PiGroup) -> np.ndarray:
        key = tuple(g.exponents.items())
        if key not in cache:
            cache[key] = g.evaluate(cols)
        return cache[key]

    target = cols[pi_set.target] if reference == "variable" else group(pi_set.target_group)
    others = [group(g) for g in pi_set.groups[1:]]
    return target, (np.column_stack(others) if others else np.empty((len(target), 0)))


def _score(scorer: Scorer, target: np.ndarray, groups: np.ndarray) -> tuple[float, int, int, str]:
    mask = scorer.domain(target, groups)
    used = int(mask.sum())
    if used < scorer.min_rows:
        return np.nan, used, len(target) - used, f"only {used} usable rows (< {scorer.min_rows} for {scorer.name})"
    value = float(scorer.score(target[mask], groups[mask]))
    if not np.isfinite(value):
        return np.nan, used, len(target) - used, f"{scorer.name} returned {value} on {used} rows"
    return value, used, len(target) - used, ""
