"""Soil resistance on a bucket from the fundamental earthmoving equation (Reece 1964; McKyes 1985).

A blade of width w at depth d with rake angle ρ (blade from the direction of travel) in Mohr–Coulomb soil
needs ``P = w (γ d² N_γ + c d N_c + q d N_q + c_a d N_ca)``; the failure angle β minimises P. P acts at the
soil–metal friction angle δ from the blade normal, so it resists travel with ``P sin(ρ+δ)`` and presses the
blade into the soil with ``P cos(ρ+δ)``. Formulas as in ``shared/reference/physics.md``.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from scaletwin_envs.specs.soil import SoilSpec

RAKE_MIN, RAKE_MAX = math.radians(15.0), math.radians(90.0)
_RAKES = np.linspace(RAKE_MIN, RAKE_MAX, 76)
_RAKE_STEP = float(_RAKES[1] - _RAKES[0])
_BETAS = np.linspace(math.radians(5.0), math.radians(85.0), 321)


def n_factors(rake: float, phi: float, delta: float, beta: np.ndarray | float) -> tuple[np.ndarray, ...]:
    """N_γ, N_c, N_q, N_ca for rake ρ, friction φ, wall friction δ and failure angle β (all rad)."""
    cot = lambda a: 1.0 / np.tan(a)  # noqa: E731
    with np.errstate(divide="ignore", invalid="ignore"):  # wedges with a vanishing denominator do not exist
        denom = np.cos(rake + delta) + np.sin(rake + delta) * cot(np.asarray(beta) + phi)
        n_gamma = (cot(beta) + cot(rake)) / (2.0 * denom)
        n_c = (1.0 + cot(beta) * cot(np.asarray(beta) + phi)) / denom
        n_ca = (1.0 - cot(rake) * cot(np.asarray(beta) + phi)) / denom
    return n_gamma, n_c, 2.0 * n_gamma, n_ca


@lru_cache(maxsize=64)
def _table(soil: SoilSpec) -> tuple[list[float], list[float]]:
    """Per rake: the β-minimised coefficients of d² (γ N_γ) and of d (c N_c + c_a N_ca), per unit width."""
    quad = np.empty_like(_RAKES)
    lin = np.empty_like(_RAKES)
    for k, rake in enumerate(_RAKES):
        ng, nc, _, nca = n_factors(rake, soil.friction_angle, soil.wall_friction_angle, _BETAS)
        # Minimise at a reference depth of 1 m; the minimising β barely moves with depth. A wedge that does not
        # exist has infinite factors, and 0 × inf (a soil without cohesion or adhesion) is NaN: masked below.
        with np.errstate(invalid="ignore"):
            total = soil.unit_weight * ng + soil.cohesion * nc + soil.adhesion * nca
        valid = np.isfinite(total) & (ng > 0)
        best = int(np.argmin(np.where(valid, total, np.inf)))
        quad[k] = soil.unit_weight * ng[best]
        lin[k] = max(soil.cohesion * nc[best] + soil.adhesion * nca[best], 0.0)
    return quad.tolist(), lin.tolist()


class SoilResistance:
    """The soil's constants of :func:`blade_force`, :func:`bearing_pressure` and :func:`side_drag`, worked out once
    (the β-minimised table, the bearing factors, K0, tan δ), for callers that evaluate them several times per
    control step; the same arithmetic as those functions, which delegate to it."""

    def __init__(self, soil: SoilSpec) -> None:
        self.quad, self.lin = _table(soil)
        self.delta = soil.wall_friction_angle
        phi = soil.friction_angle
        n_q = math.exp(math.pi * math.tan(phi)) * math.tan(math.pi / 4 + phi / 2) ** 2  # Prandtl–Reissner
        self.n_q, self.n_c = n_q, (n_q - 1.0) / math.tan(phi) if phi > 1e-6 else math.pi + 2.0
        self.cohesion, self.unit_weight, self.adhesion = soil.cohesion, soil.unit_weight, soil.adhesion
        self.k0 = 1.0 - math.sin(phi)  # at-rest earth pressure coefficient (Jaky)
        self.tan_delta = math.tan(soil.wall_friction_angle)

    def blade(self, width: float, depth: float, rake: float) -> tuple[float, float]:
        """:func:`blade_force`."""
        if depth <= 0.0:
            return 0.0, 0.0
        quad, lin = self.quad, self.lin
        r = RAKE_MIN if rake < RAKE_MIN else rake  # the rake clamped to the table: min(max(rake, MIN), MAX)
        r = RAKE_MAX if r > RAKE_MAX else r
        k, last = int((r - RAKE_MIN) / _RAKE_STEP), len(quad) - 2
        k = last if last < k else k
        t = (r - RAKE_MIN) / _RAKE_STEP - k
        p = width * (((1 - t) * quad[k] + t * quad[k + 1]) * depth * depth
                     + ((1 - t) * lin[k] + t * lin[k + 1]) * depth)
        return p * math.sin(r + self.delta), p * math.cos(r + self.delta)

    def bearing(self, depth: float) -> float:
        """:func:`bearing_pressure`."""
        return self.cohesion * self.n_c + self.unit_weight * max(depth, 0.0) * self.n_q

    def side(self, depth: float, length: float) -> float:
        """:func:`side_drag`."""
        if depth <= 0.0 or length <= 0.0:
            return 0.0
        normal = 0.5 * self.k0 * self.unit_weight * depth * depth * length
        return 2.0 * (normal * self.tan_delta + self.adhesion * depth * length)


@lru_cache(maxsize=64)
def soil_resistance(soil: SoilSpec) -> SoilResistance:
    """The :class:`SoilResistance` of a soil (cached)."""
    return SoilResistance(soil)


def blade_force(soil: SoilSpec, width: float, depth: float, rake: float) -> tuple[float, float]:
    """Resistance along travel and force pressing into the soil (N) of a blade at ``depth`` (m)."""
    return soil_resistance(soil).blade(width, depth, rake)


def bearing_pressure(soil: SoilSpec, depth: float) -> float:
    """Ultimate bearing pressure at the cutting edge (Pa): c N_c + γ d N_q (Prandtl–Reissner factors)."""
    return soil_resistance(soil).bearing(depth)


def side_drag(soil: SoilSpec, depth: float, length: float) -> float:
    """Friction and adhesion on both side plates (N) buried ``depth`` over ``length`` (m), at-rest pressure."""
    return soil_resistance(soil).side(depth, length)
