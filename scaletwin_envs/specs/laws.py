"""Scaling laws: how a loader's parameters change with its length ratio λ (relative to the ER12).

Each law is a set of power-law exponents, ``factor = λ ** exponent``, applied to the ER12 reference.

* :data:`FROUDE` is exact geometric similarity at equal density and gravity: L ∝ λ, m ∝ λ³, p ∝ λ,
  v ∝ √λ, t ∝ √λ. Under it every dimensionless signal of a cohesionless dig is scale-free.
* :data:`PRODUCT_LINE` follows how real loader lines depart from similarity (``shared/reference/physics.md``):
  relief pressure nearly constant (λ^0.2) and cylinder bores growing a little faster than length, so hydraulic
  force ∝ λ^2.7 against weight ∝ λ^2.93 (small machines relatively over-powered; breakout per weight falls
  slowly with size); cycle times nearly constant (cylinder speed ∝ λ^0.85, travel speed ∝ λ^0.35); operating
  mass ∝ λ^2.93, fitted so that λ = 1/7 gives ≈ 11.7 kg (the 11 kg miniature) and λ = 2 gives ≈ 24.6 t
  (the ~26 t WA475): these exponents are estimates fitted to the paper's three machines.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class ScalingLaw:
    """Exponents of λ for each family of parameters (dimensionless)."""

    name: str
    mass: float
    pressure: float
    bore: float
    cylinder_speed: float
    travel_speed: float

    def factors(self, scale: float) -> dict[str, float]:
        """Multiplicative factors relative to the ER12 at length ratio ``scale``."""
        return {
            "length": scale,
            "mass": scale**self.mass,
            "pressure": scale**self.pressure,
            "bore": scale**self.bore,
            "cylinder_speed": scale**self.cylinder_speed,
            "travel_speed": scale**self.travel_speed,
            "bucket_size": 1.0,
            "traction": 1.0,
        }

    def to_dict(self) -> dict[str, float | str]:
        return asdict(self)


FROUDE = ScalingLaw("froude", mass=3.0, pressure=1.0, bore=1.0, cylinder_speed=0.5, travel_speed=0.5)
PRODUCT_LINE = ScalingLaw("product_line", mass=2.93, pressure=0.2, bore=1.25, cylinder_speed=0.85, travel_speed=0.35)
LAWS: dict[str, ScalingLaw] = {law.name: law for law in (FROUDE, PRODUCT_LINE)}

#: Keys accepted by ``distortion={...}``: extra factors multiplied onto the law's (1.0 = no distortion).
DISTORTION_KEYS = ("mass", "pressure", "bore", "cylinder_speed", "travel_speed", "bucket_size", "traction")


def make_law(law: str | ScalingLaw) -> ScalingLaw:
    if isinstance(law, ScalingLaw):
        return law
    if law in LAWS:
        return LAWS[law]
    raise ValueError(f"law must be one of {sorted(LAWS)} or a ScalingLaw, got {law!r}")
