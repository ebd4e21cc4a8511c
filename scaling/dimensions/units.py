"""Unit strings -> exact dimension vectors over the SI base dimensions.

One shared :class:`pint.UnitRegistry` (:data:`UREG`) parses every unit string. A unit's *dimension vector* maps the
base dimensions it uses (``mass``, ``length``, ``time``, ``current``, ``temperature``, ``amount``, ``luminosity``)
to exact :class:`~fractions.Fraction` exponents; the scale of the unit (``kN`` vs ``N``, ``mm`` vs ``m``) is
irrelevant to dimensional analysis and is dropped. Angles (``rad``, ``deg``) are dimensionless, as in pint and SI.
"""

from __future__ import annotations

from collections.abc import Mapping
from fractions import Fraction
from functools import lru_cache

import pint

UREG = pint.UnitRegistry()
"""The one unit registry shared by the package (pint quantities from different registries do not mix)."""

BASE_DIMENSIONS: tuple[str, ...] = ("mass", "length", "time", "current", "temperature", "amount", "luminosity")
"""Canonical order of the base dimensions (rows of every dimension matrix)."""

_PINT_NAMES = {f"[{d}]": d for d in BASE_DIMENSIONS if d != "amount"} | {"[substance]": "amount"}
_DIMENSIONLESS_WORDS = frozenset({"", "1", "dimensionless", "-"})


def parse_unit(unit: str, name: str = "?") -> pint.Unit:
    """Parse ``unit`` with the shared registry.

    Args:
        unit: a pint unit expression, e.g. ``"N"``, ``"m/s^2"``, ``"Pa*s"``; ``""``, ``"1"`` and
            ``"dimensionless"`` mean a pure number.
        name: the variable the unit belongs to, used only in error messages.

    Raises:
        ValueError: ``unit`` is not a string or not a unit pint understands (the message names ``name``).
    """
    if not isinstance(unit, str):
        raise ValueError(f"variable {name!r}: unit must be a string, got {unit!r} ({type(unit).__name__})")
    text = unit.strip()
    if text.lower() in _DIMENSIONLESS_WORDS:
        return UREG.dimensionless
    try:
        return UREG.parse_units(text)
    except Exception as exc:  # pint raises many unrelated types (AssertionError, TypeError, ...) on bad syntax
        raise ValueError(f"variable {name!r}: cannot parse unit {unit!r} ({type(exc).__name__}: {exc})") from exc


def dimension_vector(unit: str, name: str = "?") -> dict[str, Fraction]:
    """Exact exponents of the base dimensions of ``unit``; dimensions with exponent 0 are omitted.

    Example: ``dimension_vector("N") == {"mass": 1, "length": 1, "time": -2}``; ``dimension_vector("rad") == {}``.

    Raises:
        ValueError: bad unit string, or a dimension outside :data:`BASE_DIMENSIONS`.
    """
    if not isinstance(unit, str):
        parse_unit(unit, name)  # raises the ValueError naming the variable
    return dict(_dimension_items(unit, name))


@lru_cache(maxsize=1024)
def _dimension_items(unit: str, name: str) -> tuple[tuple[str, Fraction], ...]:
    out: list[tuple[str, Fraction]] = []
    for pint_dim, exp in parse_unit(unit, name).dimensionality.items():
        if pint_dim not in _PINT_NAMES:
            raise ValueError(f"variable {name!r}: unit {unit!r} has non-base dimension {pint_dim}")
        value = Fraction(exp).limit_denominator(1000)
        if abs(float(value) - float(exp)) > 1e-9:
            raise ValueError(f"variable {name!r}: unit {unit!r} has a non-rational exponent {exp} on {pint_dim}")
        if value != 0:
            out.append((_PINT_NAMES[pint_dim], value))
    return tuple(out)


def dimension_vectors(variables: Mapping[str, str]) -> dict[str, dict[str, Fraction]]:
    """:func:`dimension_vector` of every ``name -> unit`` entry of ``variables``."""
    return {name: dimension_vector(unit, name) for name, unit in variables.items()}


def used_dimensions(vectors: Mapping[str, Mapping[str, Fraction]]) -> tuple[str, ...]:
    """Base dimensions with a non-zero exponent in at least one vector, in :data:`BASE_DIMENSIONS` order."""
    used = {d for vec in vectors.values() for d, e in vec.items() if e != 0}
    return tuple(d for d in BASE_DIMENSIONS if d in used)


def dimension_of(exponents: Mapping[str, Fraction], variables: Mapping[str, str]) -> dict[str, Fraction]:
    """Dimension vector of ``prod(variable ** exponent)``; ``{}`` means dimensionless.

    Raises:
        ValueError: an exponent refers to a variable missing from ``variables``, or a unit is bad.
    """
    missing = sorted(set(exponents) - set(variables))
    if missing:
        raise ValueError(f"variables {missing} have no unit; known: {sorted(variables)}")
    total: dict[str, Fraction] = {}
    for var, exp in exponents.items():
        for dim, e in dimension_vector(variables[var], var).items():
            total[dim] = total.get(dim, Fraction(0)) + Fraction(exp) * e
    return {d: total[d] for d in BASE_DIMENSIONS if total.get(d, 0) != 0}


def conversion_factor(unit: str, name: str = "?") -> float:
    """Factor that converts a value in ``unit`` to SI base units (``conversion_factor("mm") == 1e-3``).

    Offset units (``degC``) have no single factor and raise ``ValueError``.
    """
    try:
        return float(UREG.Quantity(1.0, parse_unit(unit, name)).to_base_units().magnitude)
    except pint.errors.OffsetUnitCalculusError as exc:
        raise ValueError(f"variable {name!r}: offset unit {unit!r} has no conversion factor") from exc
