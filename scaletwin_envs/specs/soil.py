"""Soils of the pile: Mohr–Coulomb parameters for the fundamental earthmoving equation.

Values are mid-range figures of the table in ``shared/reference/physics.md`` (handbook ranges and soil
property sheets; gravel is marked there as an estimate).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields


@dataclass(frozen=True)
class SoilSpec:
    """A soil, SI units.

    Attributes:
        name: label.
        unit_weight: γ, N/m³ (bulk, in the pile).
        cohesion: c, Pa.
        friction_angle: φ, rad.
        wall_friction_angle: δ, soil–metal friction angle, rad.
        adhesion: c_a, soil–metal adhesion, Pa.
        repose_angle: slope of a tipped pile, rad.
    """

    name: str
    unit_weight: float
    cohesion: float
    friction_angle: float
    wall_friction_angle: float
    adhesion: float = 0.0
    repose_angle: float = math.radians(35.0)

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name != "name" and not (isinstance(v, int | float) and math.isfinite(v)):
                raise ValueError(f"SoilSpec.{f.name} must be a finite number, got {v!r}")
        if self.unit_weight <= 0:
            raise ValueError(f"SoilSpec.unit_weight must be > 0 N/m^3, got {self.unit_weight}")
        if self.cohesion < 0 or self.adhesion < 0:
            raise ValueError("SoilSpec.cohesion and adhesion must be >= 0 Pa")
        for name in ("friction_angle", "wall_friction_angle", "repose_angle"):
            if not 0.0 <= getattr(self, name) < math.pi / 2:
                raise ValueError(f"SoilSpec.{name} must be in [0, pi/2) rad, got {getattr(self, name)}")

    @property
    def density(self) -> float:
        """Bulk density, kg/m³."""
        return self.unit_weight / 9.81

    @property
    def is_cohesive(self) -> bool:
        return self.cohesion > 0.0 or self.adhesion > 0.0

    def to_dict(self) -> dict[str, float | str]:
        return asdict(self)


def _soil(name: str, gamma_kn: float, c_kpa: float, phi_deg: float, delta_deg: float, repose_deg: float) -> SoilSpec:
    return SoilSpec(name, gamma_kn * 1e3, c_kpa * 1e3, math.radians(phi_deg), math.radians(delta_deg),
                    adhesion=0.5 * c_kpa * 1e3, repose_angle=math.radians(repose_deg))


#: Named soils (physics.md table; adhesion taken as half the cohesion, an estimate).
SOILS: dict[str, SoilSpec] = {
    "gravel": _soil("gravel", 17.5, 0.0, 38.0, 24.0, 37.0),  # dry gravel pile, estimate
    "sand": _soil("sand", 17.0, 0.0, 30.0, 18.0, 32.0),  # loose sand, delta = 0.6 phi
    "sandy_loam": _soil("sandy_loam", 15.0, 10.0, 35.0, 22.0, 38.0),
    "clay_loam": _soil("clay_loam", 14.0, 30.0, 10.0, 6.0, 40.0),
}


def make_soil(soil: str | SoilSpec) -> SoilSpec:
    """A named soil or a custom :class:`SoilSpec`."""
    if isinstance(soil, SoilSpec):
        return soil
    if isinstance(soil, str) and soil in SOILS:
        return SOILS[soil]
    raise ValueError(f"soil must be one of {sorted(SOILS)} or a SoilSpec, got {soil!r}")
