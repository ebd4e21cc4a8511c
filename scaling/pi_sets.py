"""Candidate sets of dimensionless groups: :class:`PiSet`, their enumeration and JSON manifests.

A set is complete (``n - rank(D)`` groups), independent, dimensionless and holds the target in exactly one group;
canonical forms and conventions are those of :mod:`scaling.pi_theorem`. :func:`enumerate_pi_sets` lists every
repeating-variable choice plus small integer-exponent (lattice) combinations, deduplicated;
:func:`write_manifest` / :func:`read_manifest` store sets as JSON with rational exponents.
"""

from __future__ import annotations

import itertools
import json
import warnings
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction
from math import lcm
from pathlib import Path

import numpy as np

from scaling.groups import PiGroup
from scaling.pi_theorem import (
    Vector,
    _check_target_reachable,
    _reduce,
    _warn_no_groups,
    canonical_order,
    check_variables,
    dimension_matrix,
    exact_rank,
    make_groups,
    normalise,
    null_space_rref,
    repeating_variable_sets,
)
from scaling.units import dimension_of, dimension_vectors, used_dimensions


@dataclass(frozen=True, eq=False)
class PiSet:
    """A complete set of independent dimensionless groups for one target; ``groups[0]`` holds the target.

    Identity (``==``, ``hash``, :attr:`key`): the target and the *set* of canonical groups. Every valid set spans the
    same rational null space, so spans cannot tell sets apart; instead two sets are the same when they consist of
    the same groups, each in its canonical scaling (a group and its powers, e.g. ``Re`` and ``1/Re``, are one).
    ``origin`` / ``description`` say how the set was found and never affect identity.
    """

    groups: tuple[PiGroup, ...]
    target: str
    variables: Mapping[str, str]
    origin: str = ""
    description: str = ""

    @property
    def key(self) -> frozenset[tuple[tuple[str, Fraction], ...]]:
        """The groups, each normalised as in the module docstring (so any power of a group gives the same key)."""
        keys = []
        for g in self.groups:
            holds = self.target in g.exponents
            names = canonical_order(g.exponents, self.target if holds else None)
            keys.append(tuple(sorted(zip(names, normalise([g.exponents[n] for n in names], holds), strict=True))))
        return frozenset(keys)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, PiSet) and (self.target, self.key) == (other.target, other.key)

    def __hash__(self) -> int:
        return hash((self.target, self.key))

    @property
    def target_group(self) -> PiGroup:
        return self.groups[0]

    def expressions(self) -> list[str]:
        return [g.expression() for g in self.groups]

    def evaluate(self, data: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Group values on ``data`` (any consistent units), keyed by group name (``pi1`` first)."""
        return {g.name: g.evaluate(data) for g in self.groups}

    def validate(self) -> None:
        """Raise ``ValueError`` unless the set is complete, independent, dimensionless and holds the target once."""
        order = canonical_order(self.variables, self.target)
        vecs = dimension_vectors(self.variables)
        expected = len(order) - exact_rank([[vecs[v].get(d, 0) for v in order] for d in used_dimensions(vecs)])
        if len(self.groups) != expected:
            raise ValueError(f"{self}: {len(self.groups)} groups, expected n - rank(D) = {expected}")
        for g in self.groups:
            if dims := dimension_of(g.exponents, self.variables):
                raise ValueError(f"{self}: group {g.expression()} is not dimensionless: {dims}")
        holders = [g for g in self.groups if self.target in g.exponents]
        if len(holders) != 1 or holders[0] is not self.groups[0] or holders[0].exponents[self.target] != 1:
            raise ValueError(f"{self}: target {self.target!r} must appear once, in the first group, with exponent 1")
        if exact_rank([[g.exponents.get(v, Fraction(0)) for v in order] for g in self.groups]) != len(self.groups):
            raise ValueError(f"{self}: groups are not independent")

    def to_dict(self) -> dict[str, object]:
        return {"origin": self.origin, "description": self.description, "groups": [g.to_dict() for g in self.groups]}

    @classmethod
    def from_dict(cls, d: Mapping[str, object], target: str, variables: Mapping[str, str]) -> PiSet:
        groups = d.get("groups")
        if not isinstance(groups, list):
            raise ValueError("a PiSet entry needs a 'groups' list")
        return cls(tuple(PiGroup.from_dict(g) for g in groups), target, dict(variables),
                   str(d.get("origin", "")), str(d.get("description", "")))

    def __str__(self) -> str:
        return "{" + ", ".join(str(g) for g in self.groups) + "}"


def enumerate_pi_sets(variables: Mapping[str, str], target: str, max_exponent: int = 2, *, lattice: bool = True,
                      max_lattice_sets: int = 200, max_lattice_points: int = 500_000) -> list[PiSet]:
    """Candidate group sets for ``target``, deduplicated (see :class:`PiSet` identity), each validated.

    1. Repeating-variable sets, all of them: every ``rank(D)``-subset of the non-target variables whose dimension
       submatrix has full rank; the target is never repeating, so it lands in exactly one group.
    2. Integer-lattice sets (``lattice=True``): every primitive integer null vector with all exponents in
       ``[-max_exponent, max_exponent]`` is a candidate group (exhaustive search over the RREF coordinates,
       skipped with a warning if ``(2*max_exponent+1)**k > max_lattice_points``). A set is one target-holding
       candidate plus ``k-1`` linearly independent non-target candidates; candidates are ordered simplest first
       (fewest variables, smallest sum of |exponents|), independent subsets found depth-first in that order, and
       (target, subset) pairs taken by increasing combined rank, until ``max_lattice_sets`` new sets are found.

    Returns ``[]`` (with a warning) when no group exists. Raises ``ValueError`` as :func:`pi_groups` does.
    """
    check_variables(variables, target)
    if target is None:
        raise ValueError("enumerate_pi_sets needs a target variable")
    order = canonical_order(variables, target)
    d = dimension_matrix(variables, order)
    rows, pivots = null_space_rref(d)
    if not rows:
        _warn_no_groups(order)
        return []
    _check_target_reachable(pivots, target, variables)
    found: dict[PiSet, None] = {}

    def add(vectors: Sequence[Sequence[Fraction]], origin: str, description: str) -> None:
        groups = tuple(make_groups(vectors, order, target))
        found.setdefault(PiSet(groups, target, dict(variables), origin, description))

    for repeating, vectors in repeating_variable_sets(d, order, skip=1):
        add(vectors, "repeating", "repeating variables: " + (", ".join(repeating) or "(none)"))
    if lattice and max_exponent >= 1:
        budget = len(found) + max_lattice_sets
        for vectors in _lattice_sets(rows, pivots, max_exponent, max_lattice_sets, max_lattice_points):
            add(vectors, "lattice", f"integer exponents, |e| <= {max_exponent}")
            if len(found) >= budget:
                break
    for s in found:
        s.validate()
    return list(found)


def lattice_vectors(rows: Sequence[Vector], pivots: Sequence[int], max_exponent: int) -> list[tuple[int, ...]]:
    """All primitive integer null vectors with ``|e| <= max_exponent``, first non-zero > 0, simplest first.

    Exhaustive: a null vector equals ``sum_i v[pivots[i]] * rows[i]`` (RREF), so scanning the integer coordinates
    ``v[pivots] in [-max_exponent, max_exponent]^k`` finds every such vector.
    """
    denom = lcm(*(x.denominator for row in rows for x in row))
    basis = np.array([[int(x * denom) for x in row] for row in rows], dtype=np.int64)
    coords = np.array(list(itertools.product(range(-max_exponent, max_exponent + 1), repeat=len(rows))))
    vecs = coords @ basis
    vecs = vecs[(vecs % denom == 0).all(axis=1)] // denom
    vecs = vecs[(np.abs(vecs) <= max_exponent).all(axis=1) & (vecs != 0).any(axis=1)]
    first = vecs[np.arange(len(vecs)), (vecs != 0).argmax(axis=1)]
    vecs = vecs[(first > 0) & (np.gcd.reduce(np.abs(vecs), axis=1) == 1)]
    return sorted(map(tuple, vecs.tolist()), key=lambda v: (sum(x != 0 for x in v), sum(map(abs, v)), v))


def _lattice_sets(rows: Sequence[Vector], pivots: Sequence[int], max_exponent: int, limit: int,
                  max_points: int) -> Iterator[list[tuple[int, ...]]]:
    if (2 * max_exponent + 1) ** len(rows) > max_points:
        warnings.warn(f"lattice search skipped: {(2 * max_exponent + 1) ** len(rows)} points > max_lattice_points="
                      f"{max_points}; lower max_exponent or raise the limit", stacklevel=3)
        return
    vecs = lattice_vectors(rows, pivots, max_exponent)
    targets = [v for v in vecs if v[0] != 0]
    others = [v for v in vecs if v[0] == 0]
    bases = _independent_subsets([[Fraction(v[p]) for p in pivots[1:]] for v in others], len(rows) - 1, limit)
    for s in range(len(targets) + len(bases) - 1):
        for i in range(max(0, s - len(bases) + 1), min(s, len(targets) - 1) + 1):
            yield [targets[i], *(others[b] for b in bases[s - i])]


def _independent_subsets(coords: Sequence[Vector], size: int, limit: int, steps: int = 200_000) -> list[tuple]:
    """Up to ``limit`` index tuples of ``size`` linearly independent ``coords``, depth-first, lexicographic."""
    out: list[tuple] = []
    budget = [steps]

    def dfs(start: int, chosen: tuple, echelon: list[tuple[int, Vector]]) -> None:
        if len(chosen) == size:
            out.append(chosen)
            return
        for i in range(start, len(coords) - (size - len(chosen)) + 1):
            budget[0] -= 1
            if len(out) >= limit or budget[0] < 0:
                return
            reduced = _reduce(coords[i], echelon)
            if reduced is not None:
                dfs(i + 1, (*chosen, i), [*echelon, reduced])

    dfs(0, (), [])
    return out


MANIFEST_FORMAT = "scaletwin.pi_sets"


def write_manifest(sets: Sequence[PiSet], path: str | Path) -> None:
    """Write ``sets`` (same target and variables) as JSON; exponents are rational strings (``"-1/2"``)."""
    if not sets:
        raise ValueError("write_manifest needs at least one PiSet (it records their target and variables)")
    first = sets[0]
    if any(s.target != first.target or dict(s.variables) != dict(first.variables) for s in sets):
        raise ValueError("all sets of a manifest must share one target and one variables mapping")
    payload = {"format": MANIFEST_FORMAT, "version": 1, "target": first.target, "variables": dict(first.variables),
               "n_variables": len(first.variables), "n_groups": len(first.groups), "count": len(sets),
               "sets": [s.to_dict() for s in sets]}
    Path(path).write_text(json.dumps(payload, indent=2) + "\n", encoding="utf-8")


def read_manifest(path: str | Path) -> list[PiSet]:
    """Read a :func:`write_manifest` file back; every set is re-validated against the stored units."""
    payload = json.loads(Path(path).read_text(encoding="utf-8"))
    if not isinstance(payload, dict) or payload.get("format") != MANIFEST_FORMAT:
        raise ValueError(f"{path}: not a {MANIFEST_FORMAT} manifest")
    target, variables = str(payload["target"]), dict(payload["variables"])
    sets = [PiSet.from_dict(d, target, variables) for d in payload["sets"]]
    if len(sets) != payload.get("count"):
        raise ValueError(f"{path}: 'count' is {payload.get('count')} but {len(sets)} sets are stored")
    for s in sets:
        s.validate()
    return sets
