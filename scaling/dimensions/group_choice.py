"""Choosing the paper's group sets for F21: Eq. (10) and Eq. (23) variables, π1 = F21/F31, finite at rest.

The candidate sets come from :func:`scaling.dimensions.pi_theorem.enumerate_pi_sets` (every repeating-variable choice
plus small integer-exponent combinations). Two rules narrow them before the paper's filter ranks what is left:

1. π1 must be the paper's output group ``F21/F31`` (Eq. 13).
2. Every input group must stay finite *at rest*, where the motion variables vanish (a1 = α1 = 0 for Eq. 10,
   V1 = w1 = 0 for Eq. 23): the miniature is validated at static equilibrium, and a group such as
   ``a1/(α1·x_b)`` is 0/0 there. A group whose motion variables all have exponents of one sign is kept and
   oriented so that they appear in the numerator (``m_b·a1/F31`` rather than ``F31/(a1·m_b)``; a set holds a
   group and its inverse as one, see :class:`~scaling.dimensions.pi_theorem.PiSet`), so that it is 0 at rest; a group
   mixing signs is not finite at rest and rules its set out.

The admissible sets are ranked by a scorer of :mod:`scaling.dimensions.selection` (default: the paper's RMS of Pearson
correlations, ``PearsonRMS``), with the shuffled-data baseline; the whole ranking is returned with the winner.

``"eq10+pose"`` (our extension, not in the paper) is the Eq. (10) winner plus the linkage pose: the boom angle
and the bucket pitch (rad, from each machine's reference digging pose). Dimensionless variables are groups by
themselves; the pose sets the lever arms between the pin and cylinder forces, which Eq. (10) does not carry, and
lifts the FFNN's held-out R² of δ1 from about 0.98 to above 0.99 (``benchmarks/results/scaling_targets.md``).

Finally each input group of the winner without a motion variable is oriented *for the data*
(:func:`orient_for_data`): a variable that changes sign in the data (the cylinder forces pass through zero) is
moved to the numerator, so that the group crosses zero smoothly instead of jumping between ±∞
(``Pf_tilt/F31``, not ``F31/Pf_tilt``). Ranking is unaffected: the paper's filter already scores each group in
its better orientation.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction

import numpy as np
import pandas as pd

from scaling.dimensions.groups import PiGroup
from scaling.dimensions.pi_theorem import PiSet, enumerate_pi_sets
from scaling.dimensions.scorers import Scorer
from scaling.dimensions.selection import rank_pi_sets

#: Eq. (10): F21 = F21(F31, Pf_tilt, Pf_lift, x_b, y_b, m_b, a1, α1), SI units.
EQ10: dict[str, str] = {"F21": "N", "F31": "N", "Pf_tilt": "N", "Pf_lift": "N", "x_b": "m", "y_b": "m",
                        "m_b": "kg", "a1": "m/s^2", "alpha1": "rad/s^2"}
#: Eq. (23): as Eq. (10) with the bucket speed V1 and angular speed w1 in place of a1 and α1.
EQ23: dict[str, str] = {**{k: v for k, v in EQ10.items() if k not in ("a1", "alpha1")}, "V1": "m/s", "w1": "rad/s"}
#: Variables that vanish at rest, per variable list.
AT_REST: dict[str, tuple[str, ...]] = {"eq10": ("a1", "alpha1"), "eq23": ("V1", "w1")}
VARIABLES: dict[str, dict[str, str]] = {"eq10": EQ10, "eq23": EQ23}
#: The pose groups appended by the ``+pose`` variants: angles (rad) are dimensionless, each a group by itself.
POSE: dict[str, str] = {"boom_angle": "rad", "bucket_pitch": "rad"}
POSE_GROUPS: tuple[PiGroup, ...] = tuple(PiGroup({v: Fraction(1)}, name=v) for v in POSE)
POSE_SUFFIX = "+pose"
#: The paper's output group (Eq. 13).
PI1 = PiGroup({"F21": Fraction(1), "F31": Fraction(-1)}, name="pi1")


def orient_at_rest(group: PiGroup, vanishing: Sequence[str]) -> PiGroup | None:
    """``group`` or its inverse, whichever has the vanishing variables in the numerator (0 at rest); the group
    itself if it has none; ``None`` if it mixes signs (0/0 at rest)."""
    signs = {e > 0 for v, e in group.exponents.items() if v in vanishing}
    if not signs:
        return group
    if len(signs) > 1:
        return None
    if signs == {True}:
        return group
    return PiGroup({k: -e for k, e in group.exponents.items()}, name=group.name)


def at_rest_version(pi_set: PiSet, vanishing: Sequence[str]) -> PiSet | None:
    """The set with every input group oriented by :func:`orient_at_rest`; ``None`` if one is not finite at rest."""
    groups = [orient_at_rest(g, vanishing) for g in pi_set.groups[1:]]
    if any(g is None for g in groups):
        return None
    return PiSet((pi_set.groups[0], *groups), pi_set.target, dict(pi_set.variables), pi_set.origin,  # type: ignore[arg-type]
                 pi_set.description)


def sign_changing(data: pd.DataFrame, variables: Sequence[str], share: float = 1e-3) -> set[str]:
    """Variables of ``variables`` with at least ``share`` of their finite values on each side of zero."""
    out = set()
    for v in variables:
        x = np.asarray(data[v], dtype=float)
        x = x[np.isfinite(x)]
        if x.size and min(np.mean(x > 0), np.mean(x < 0)) >= share:
            out.add(v)
    return out


def orient_for_data(pi_set: PiSet, data: pd.DataFrame, vanishing: Sequence[str]) -> PiSet:
    """``pi_set`` with each input group free of ``vanishing`` variables inverted when a variable that changes sign
    in ``data`` sits only in its denominator (the group would jump between ±∞ as that variable crosses zero)."""
    changing = sign_changing(data, list(pi_set.variables))
    groups = [pi_set.groups[0]]
    for g in pi_set.groups[1:]:
        down = {k for k, e in g.exponents.items() if e < 0} & changing
        up = {k for k, e in g.exponents.items() if e > 0} & changing
        if down and not up and not any(v in g.exponents for v in vanishing):
            g = PiGroup({k: -e for k, e in g.exponents.items()}, name=g.name)
        groups.append(g)
    return PiSet(tuple(groups), pi_set.target, dict(pi_set.variables), pi_set.origin, pi_set.description)


def admissible_sets(variables: Mapping[str, str], vanishing: Sequence[str], output: PiGroup = PI1,
                    max_exponent: int = 2) -> list[PiSet]:
    """Candidate sets with ``output`` as π1 and every input group finite at rest (module rules), oriented."""
    target = next(k for k, e in output.exponents.items() if e == 1)
    out = []
    for s in enumerate_pi_sets(dict(variables), target, max_exponent):
        if s.target_group != output:
            continue
        if (oriented := at_rest_version(s, vanishing)) is not None:
            out.append(oriented)
    return out


@dataclass(frozen=True)
class GroupChoice:
    """The chosen set and the ranking of all admissible sets (``ranking.attrs`` holds the scorer settings)."""

    name: str
    pi_set: PiSet
    ranking: pd.DataFrame
    n_candidates: int

    @property
    def inputs(self) -> tuple[PiGroup, ...]:
        return tuple(self.pi_set.groups[1:])

    @property
    def output(self) -> PiGroup:
        return self.pi_set.groups[0]

    def describe(self) -> str:
        return (f"{self.name}: π1 = {self.output.expression()}; inputs "
                + ", ".join(g.expression() for g in self.inputs)
                + f"  (best of {len(self.ranking)} admissible of {self.n_candidates} candidate sets)")


def choose_groups(data: pd.DataFrame, name: str = "eq10", scorer: str | Scorer = "pearson", n_shuffles: int = 10,
                  seed: int = 0) -> GroupChoice:
    """Rank the admissible sets of variable list ``name`` (``"eq10"`` or ``"eq23"``, each optionally with
    ``"+pose"``) on ``data``; best first.

    Raises:
        ValueError: unknown list, or no admissible set.
    """
    if name.endswith(POSE_SUFFIX):
        return with_pose(choose_groups(data, name.removesuffix(POSE_SUFFIX), scorer, n_shuffles, seed))
    if name not in VARIABLES:
        known = sorted(VARIABLES) + [v + POSE_SUFFIX for v in sorted(VARIABLES)]
        raise ValueError(f"unknown variable list {name!r}; choose from {known}")
    variables = VARIABLES[name]
    target = next(k for k, e in PI1.exponents.items() if e == 1)
    n_candidates = len(enumerate_pi_sets(variables, target))
    sets = admissible_sets(variables, AT_REST[name])
    if not sets:
        raise ValueError(f"no candidate set of {name} has π1 = {PI1.expression()} and groups finite at rest")
    ranking = rank_pi_sets(sets, data, scorer, n_shuffles, seed=seed)
    best = orient_for_data(sets[int(ranking.iloc[0]["set_id"])], data, AT_REST[name])
    return GroupChoice(name, best, ranking, n_candidates)


def with_pose(choice: GroupChoice) -> GroupChoice:
    """``choice`` with the pose groups (:data:`POSE_GROUPS`) appended to its inputs; named ``<name>+pose``."""
    s = choice.pi_set
    posed = PiSet((*s.groups, *POSE_GROUPS), s.target, {**s.variables, **POSE}, s.origin,
                  (s.description + " + pose angles").strip())
    return GroupChoice(choice.name + POSE_SUFFIX, posed, choice.ranking, choice.n_candidates)
