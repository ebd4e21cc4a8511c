"""Buckingham-Pi analysis with exact rational arithmetic: groups, candidate group sets and their JSON manifests.

Conventions (all output is independent of the order in which variables are given):

* Canonical variable order: the target first, then the other variable names sorted (Python string order).
* Count: ``n - rank(D)`` groups, where ``D`` is the dimension matrix (used base dimensions x variables).
* Target group ``pi1``: the only group containing the target, with target exponent exactly ``+1`` (other exponents
  may then be fractions, e.g. ``T*g^(1/2)/L^(1/2)``).
* Other groups: primitive integer exponent vectors (gcd 1) whose first non-zero exponent in canonical order is > 0.
* Groups of a set are ordered by the canonical position of their first variable, then by exponents; named pi1..pik.
* :func:`pi_groups` returns the reduced-row-echelon (RREF) basis of the rational null space of ``D`` over the
  canonical order, normalised as above. Its non-pivot columns are the repeating variables, so the basis equals the
  repeating-variable set whose repeating variables are the lexicographically last independent ones.

Candidate *sets* of groups (:class:`PiSet`): a set is complete (``n - rank(D)`` groups), independent,
dimensionless and holds the target in exactly one group, each group in the canonical form above.
:func:`enumerate_pi_sets` lists every repeating-variable choice plus small integer-exponent (lattice) combinations,
deduplicated; :func:`write_manifest` / :func:`read_manifest` store sets as JSON with rational exponents.
"""

from __future__ import annotations

import itertools
import json
import warnings
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction
from math import gcd, lcm
from pathlib import Path

import numpy as np
import sympy

from scaling.dimensions.groups import PiGroup
from scaling.dimensions.units import dimension_of, dimension_vectors, used_dimensions

Vector = list[Fraction]


# --------------------------------------------------------------------------------------------------------------------
# exact null spaces and canonical groups
# --------------------------------------------------------------------------------------------------------------------


def canonical_order(variables: Mapping[str, str], target: str | None) -> tuple[str, ...]:
    """The target first, then the other variable names sorted."""
    others = sorted(v for v in variables if v != target)
    return (target, *others) if target is not None else tuple(others)


def check_variables(variables: Mapping[str, str], target: str | None) -> None:
    """Raise ``ValueError`` for an empty mapping, blank/non-string names, or a target that is not a variable."""
    if not isinstance(variables, Mapping) or not variables:
        raise ValueError("variables must be a non-empty mapping of name -> unit string")
    bad = [k for k in variables if not isinstance(k, str) or not k.strip()]
    if bad:
        raise ValueError(f"variable names must be non-empty strings, got {bad!r}")
    if target is not None and target not in variables:
        raise ValueError(f"target {target!r} is not one of the variables {sorted(variables)}")


def dimension_matrix(variables: Mapping[str, str], order: Sequence[str]) -> sympy.Matrix:
    """Exact dimension matrix: one row per used base dimension (SI order), one column per name in ``order``."""
    vecs = dimension_vectors({name: variables[name] for name in order})
    dims = used_dimensions(vecs)
    return sympy.Matrix(len(dims), len(order), lambda i, j: _rat(vecs[order[j]].get(dims[i], 0)))


def null_space_rref(d: sympy.Matrix) -> tuple[list[Vector], tuple[int, ...]]:
    """RREF basis of the rational null space of ``d`` (rows) and its pivot columns; ``([], ())`` if trivial."""
    basis = d.nullspace()
    if not basis:
        return [], ()
    rref, pivots = sympy.Matrix.hstack(*basis).T.rref()
    rows = [[_frac(rref[i, j]) for j in range(rref.cols)] for i in range(rref.rows)]
    return rows, tuple(pivots)


def normalise(vec: Sequence[Fraction], target_first: bool) -> Vector:
    """Canonical scaling of an exponent vector (see module docstring); ``target_first``: index 0 is the target."""
    if target_first and vec[0] != 0:
        return [Fraction(x) / vec[0] for x in vec]
    scale = lcm(*(Fraction(x).denominator for x in vec))
    ints = [int(Fraction(x) * scale) for x in vec]
    g = gcd(*ints)
    sign = 1 if next(x for x in ints if x != 0) > 0 else -1
    return [Fraction(sign * x, g) for x in ints]


def make_groups(vectors: Sequence[Sequence[Fraction]], order: Sequence[str], target: str | None) -> list[PiGroup]:
    """Normalise, sort and name exponent vectors (over ``order``) as ``pi1..pik`` groups."""
    normed = [normalise(v, target is not None) for v in vectors]
    normed.sort(key=lambda v: (next(i for i, x in enumerate(v) if x != 0), [-x for x in v]))
    return [PiGroup(dict(zip(order, v, strict=True)), name=f"pi{i + 1}") for i, v in enumerate(normed)]


def pi_groups(variables: Mapping[str, str], target: str | None = None) -> list[PiGroup]:
    """A canonical complete set of independent dimensionless groups.

    Args:
        variables: ``name -> unit string`` (pint syntax, e.g. ``{"T": "s", "L": "m", "m": "kg", "g": "m/s^2"}``).
        target: the output variable; it appears only in ``pi1``, with exponent +1. A dimensionless target
            gives ``pi1 = target``.

    Returns:
        ``n - rank(D)`` groups in the canonical form of the module docstring; ``[]`` (with a warning) when the
        variables are dimensionally independent (``n == rank``) so that no group exists.

    Raises:
        ValueError: bad names or units, unknown target, or a target whose dimension cannot be cancelled by the
            other variables (it would appear in no group).
    """
    order, _, rows, _ = _analyse(variables, target)
    return make_groups(rows, order, target) if rows else []


def repeating_variable_sets(d: sympy.Matrix, order: Sequence[str], skip: int) -> list[tuple[tuple[str, ...], list]]:
    """Every repeating-variable choice: ``rank(d)``-subsets of columns ``skip..`` with full-rank dimension submatrix.

    Returns ``(repeating names, exponent vectors)`` pairs; each non-repeating variable ``v`` gives the group
    ``v * prod(r ** e_r)`` with the exponents ``e`` solved exactly (unique because the submatrix has full rank).
    """
    rank = d.rank()
    out = []
    for combo in itertools.combinations(range(skip, len(order)), rank):
        sub = d[:, list(combo)]
        if rank and sub.rank() < rank:
            continue
        solve = (sub.T * sub).inv() * sub.T if rank else None
        vectors = []
        for j in (j for j in range(len(order)) if j not in combo):
            vec = [Fraction(0)] * len(order)
            vec[j] = Fraction(1)
            if solve is not None:
                for idx, e in zip(combo, -(solve * d[:, j]), strict=True):
                    vec[idx] = _frac(e)
            vectors.append(vec)
        out.append((tuple(order[i] for i in combo), vectors))
    return out


def _analyse(variables: Mapping[str, str],
             target: str | None) -> tuple[tuple[str, ...], sympy.Matrix, list[Vector], tuple[int, ...]]:
    """Checked canonical order, dimension matrix and RREF null space (rows, pivots) shared by :func:`pi_groups`
    and :func:`enumerate_pi_sets`; warns (for the public caller) when there is no group.

    Raises:
        ValueError: as :func:`check_variables`, or a target that the other variables cannot make dimensionless.
    """
    check_variables(variables, target)
    order = canonical_order(variables, target)
    d = dimension_matrix(variables, order)
    rows, pivots = null_space_rref(d)
    if not rows:
        warnings.warn(f"no dimensionless group: the {len(order)} variables {list(order)} are dimensionally "
                      "independent (rank == number of variables)", stacklevel=3)
    elif target is not None and pivots[0] != 0:
        others = sorted(v for v in variables if v != target)
        raise ValueError(
            f"target {target!r} [{variables[target]}] cannot be made dimensionless with {others}: its dimension is "
            "independent of the other variables, so it would appear in no group")
    return order, d, rows, pivots


def _rat(x: Fraction | int) -> sympy.Rational:
    x = Fraction(x)
    return sympy.Rational(x.numerator, x.denominator)


def _frac(x: sympy.Expr) -> Fraction:
    r = sympy.Rational(x)
    return Fraction(int(r.p), int(r.q))


def exact_rank(rows: Sequence[Sequence[Fraction]]) -> int:
    """Rank of a small rational matrix (given as rows), by exact elimination."""
    echelon: list[tuple[int, Vector]] = []
    for row in rows:
        if (reduced := _reduce([Fraction(x) for x in row], echelon)) is not None:
            echelon.append(reduced)
    return len(echelon)


def _reduce(vec: Vector, echelon: list[tuple[int, Vector]]) -> tuple[int, Vector] | None:
    """Eliminate ``vec`` against an incremental echelon basis; ``None`` if it is dependent."""
    v = list(vec)
    for p, row in echelon:
        if v[p]:
            v = [a - v[p] * b for a, b in zip(v, row, strict=True)]
    p = next((i for i, x in enumerate(v) if x), None)
    return None if p is None else (p, [x / v[p] for x in v])


# --------------------------------------------------------------------------------------------------------------------
# candidate sets of groups and their manifests
# --------------------------------------------------------------------------------------------------------------------


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
    if target is None:
        raise ValueError("enumerate_pi_sets needs a target variable")
    order, d, rows, pivots = _analyse(variables, target)
    if not rows:
        return []
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
