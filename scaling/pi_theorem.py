"""Buckingham-Pi groups with exact rational arithmetic, and enumeration of candidate group sets.

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
The candidate *sets* of groups (:class:`PiSet`, :func:`enumerate_pi_sets`, JSON manifests) live in
:mod:`scaling.pi_sets`; they are re-exported here for compatibility.
"""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Mapping, Sequence
from fractions import Fraction
from math import gcd, lcm
from typing import Any

import sympy

from scaling.groups import PiGroup
from scaling.units import dimension_vectors, used_dimensions

Vector = list[Fraction]


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
    check_variables(variables, target)
    order = canonical_order(variables, target)
    rows, pivots = null_space_rref(dimension_matrix(variables, order))
    if not rows:
        _warn_no_groups(order)
        return []
    _check_target_reachable(pivots, target, variables)
    return make_groups(rows, order, target)


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


def _check_target_reachable(pivots: tuple[int, ...], target: str | None, variables: Mapping[str, str]) -> None:
    if target is not None and pivots[0] != 0:
        others = sorted(v for v in variables if v != target)
        raise ValueError(
            f"target {target!r} [{variables[target]}] cannot be made dimensionless with {others}: its dimension is "
            "independent of the other variables, so it would appear in no group")


def _warn_no_groups(order: Sequence[str]) -> None:
    warnings.warn(f"no dimensionless group: the {len(order)} variables {list(order)} are dimensionally independent "
                  "(rank == number of variables)", stacklevel=3)


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


_MOVED = frozenset({"PiSet", "enumerate_pi_sets", "lattice_vectors", "write_manifest", "read_manifest",
                    "MANIFEST_FORMAT"})


def __getattr__(name: str) -> Any:
    """Names that moved to :mod:`scaling.pi_sets`, imported lazily (no import cycle)."""
    if name in _MOVED:
        from scaling import pi_sets

        return getattr(pi_sets, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
