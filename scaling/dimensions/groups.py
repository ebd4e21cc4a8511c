"""The dimensionless group: a product of variables raised to exact rational exponents."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np


@dataclass(frozen=True)
class PiGroup:
    """A dimensionless group ``prod(variable ** exponent)``.

    Attributes:
        exponents: exact rational exponent of each variable; variables with a zero exponent are omitted.
        name: a short label (``"pi1"``); purely cosmetic, never used for identity.
    """

    exponents: Mapping[str, Fraction]
    name: str = field(default="pi", compare=False)

    def __post_init__(self) -> None:
        cleaned = {k: Fraction(v) for k, v in self.exponents.items() if Fraction(v) != 0}
        if not cleaned:
            raise ValueError("a PiGroup needs at least one variable with a non-zero exponent")
        object.__setattr__(self, "exponents", dict(sorted(cleaned.items())))

    @property
    def variables(self) -> tuple[str, ...]:
        return tuple(self.exponents)

    def expression(self) -> str:
        """Readable form, numerator over denominator, e.g. ``F21/F31`` or ``m_b*a1/F31``."""

        def part(items: list[tuple[str, Fraction]]) -> str:
            return "*".join(k if e == 1 else f"{k}^{_fmt(e)}" for k, e in items)

        num = [(k, e) for k, e in self.exponents.items() if e > 0]
        den = [(k, -e) for k, e in self.exponents.items() if e < 0]
        top = part(num) or "1"
        if not den:
            return top
        bottom = part(den)
        return f"{top}/({bottom})" if len(den) > 1 else f"{top}/{bottom}"

    def evaluate(self, data: Mapping[str, np.ndarray | float]) -> np.ndarray:
        """Value of the group on data (SI or any consistent units).

        Raises:
            KeyError: a variable of the group is missing from ``data``.
        """
        missing = [k for k in self.exponents if k not in data]
        if missing:
            raise KeyError(f"group {self.expression()} needs variables {missing}; got {sorted(data)}")
        out: np.ndarray | float = 1.0
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            for k, e in self.exponents.items():
                out = out * np.power(np.asarray(data[k], dtype=float), float(e))
        return np.asarray(out, dtype=float)

    def to_dict(self) -> dict[str, object]:
        return {"name": self.name, "expression": self.expression(),
                "exponents": {k: str(e) for k, e in self.exponents.items()}}

    @classmethod
    def from_dict(cls, d: Mapping[str, object]) -> PiGroup:
        exps = d["exponents"]
        if not isinstance(exps, Mapping):
            raise ValueError("PiGroup 'exponents' must be a mapping of variable -> rational string")
        return cls({str(k): Fraction(str(v)) for k, v in exps.items()}, name=str(d.get("name", "pi")))

    def __str__(self) -> str:
        return f"{self.name} = {self.expression()}"


def _fmt(e: Fraction) -> str:
    return str(e.numerator) if e.denominator == 1 else f"({e})"
