"""Dimensionless groups of the Eq. (10)/(23) signals, logged beside the raw signals.

Each group is a ratio that is equal on two machines in exact (Froude) similarity, so plotting them for two
sizes shows the distortion at a glance. ``L`` is the boom length (m), ``g`` = 9.81 m/s².
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

import numpy as np

from scaletwin_envs.specs.loader import GRAVITY

Values = Mapping[str, np.ndarray | float]

#: Group name → (label, function of the signals and L). Names are entity-path safe.
GROUPS: dict[str, tuple[str, Callable[[Values, float], np.ndarray]]] = {
    "F21_over_F31": ("F21/F31", lambda s, L: _div(s["F21"], s["F31"])),
    "F21_over_mb_g": ("F21/(m_b g)", lambda s, L: _div(s["F21"], np.multiply(s["m_b"], GRAVITY))),
    "Pf_lift_over_F31": ("Pf_lift/F31", lambda s, L: _div(s["Pf_lift"], s["F31"])),
    "Pf_tilt_over_F21": ("Pf_tilt/F21", lambda s, L: _div(s["Pf_tilt"], s["F21"])),
    "x_b_over_L": ("x_b/L", lambda s, L: _div(s["x_b"], L)),
    "y_b_over_L": ("y_b/L", lambda s, L: _div(s["y_b"], L)),
    "a1_over_g": ("a1/g", lambda s, L: _div(s["a1"], GRAVITY)),
    "alpha1_L_over_g": ("alpha1 L/g", lambda s, L: _div(np.multiply(s["alpha1"], L), GRAVITY)),
    "V1_over_sqrt_gL": ("V1/sqrt(gL)", lambda s, L: _div(s["V1"], math.sqrt(GRAVITY * L) if L > 0 else 0.0)),
    "w1_sqrt_L_over_g": ("w1 sqrt(L/g)", lambda s, L: np.multiply(s["w1"], math.sqrt(max(L, 0.0) / GRAVITY))),
}
#: Groups that need L (NaN when L is unknown).
NEEDS_LENGTH = frozenset({"x_b_over_L", "y_b_over_L", "alpha1_L_over_g", "V1_over_sqrt_gL", "w1_sqrt_L_over_g"})


def dimensionless_groups(signals: Values, length: float | None) -> dict[str, np.ndarray]:
    """Every group of :data:`GROUPS` whose signals are present, as float arrays (scalars give 0-d arrays).

    Args:
        signals: SI signals (arrays or floats) by name.
        length: boom length L, m; None (unknown machine) makes the L-dependent groups NaN.
    """
    out: dict[str, np.ndarray] = {}
    for name, (_, fn) in GROUPS.items():
        try:
            value = fn(signals, length if length is not None else math.nan)
        except KeyError:
            continue
        out[name] = np.asarray(value, dtype=np.float64)
        if length is None and name in NEEDS_LENGTH:
            out[name] = np.full_like(out[name], math.nan)
    return out


def _div(a: np.ndarray | float, b: np.ndarray | float) -> np.ndarray:
    """a / b with NaN where b is 0 (a pin carrying no load has no ratio)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(b != 0.0, a / np.where(b != 0.0, b, 1.0), math.nan)
