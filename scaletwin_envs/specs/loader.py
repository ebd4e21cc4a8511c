"""The loader specification: Z-bar linkage geometry, masses, hydraulics and bucket, at any scale.

Coordinates are planar (x forward, z up) in the machine frame, metres, with the origin on the ground below the
boom pivot. Pins are given in the *reference pose*: boom lowered, bucket floor flat on the ground, which is
the pose the MuJoCo model is built in (all joint positions zero there).

Body numbering of the paper (Table 1): 1 bucket, 2 link B, 3 main arm (boom), 4 base (frame). ``F21`` is the
pin force between link B and the bucket (``pin_21``), ``F31`` the boom–bucket pin force at ``O``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

Point = tuple[float, float]
GRAVITY = 9.81  # m/s²
SCALE_RANGE = (0.05, 3.0)


@dataclass(frozen=True)
class LinkageGeometry:
    """Pin and outline coordinates in the reference pose (m, machine frame)."""

    boom_pivot: Point  # frame–boom pin
    pin_O: Point  # boom–bucket pin (O)
    bell_crank_pivot: Point  # boom–bell crank (link A) pin
    bell_crank_top: Point  # bell crank–tilt cylinder rod pin
    bell_crank_bottom: Point  # bell crank–link B pin
    pin_21: Point  # link B–bucket pin
    lift_frame_pin: Point  # lift cylinder barrel on the frame
    lift_boom_pin: Point  # lift cylinder rod on the boom
    tilt_frame_pin: Point  # tilt cylinder barrel on the frame
    bucket_heel: Point  # bucket outline: heel, cutting edge, top of the back wall
    bucket_edge: Point
    bucket_back_top: Point
    bucket_width: float  # m

    def scaled(self, length: float, bucket_size: float = 1.0) -> LinkageGeometry:
        """Every length × ``length``; the bucket shell additionally × ``bucket_size`` about the point on its floor
        below O, so that the floor stays on the ground in the reference pose."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = v * length if isinstance(v, float) else (v[0] * length, v[1] * length)
        ox, oz = out["pin_O"][0], out["bucket_heel"][1]
        for name in ("bucket_heel", "bucket_edge", "bucket_back_top"):
            x, z = out[name]
            out[name] = (ox + (x - ox) * bucket_size, oz + (z - oz) * bucket_size)
        out["bucket_width"] *= bucket_size
        return LinkageGeometry(**out)

    @property
    def boom_length(self) -> float:
        """Boom pivot to O, m: the machine's characteristic length."""
        return math.dist(self.boom_pivot, self.pin_O)


@dataclass(frozen=True)
class CylinderSpec:
    """A hydraulic cylinder circuit (``count`` identical cylinders acting in parallel).

    Attributes:
        bore: piston diameter, m.  rod_diameter: m.
        closed_length: pin-to-pin length fully retracted, m.  stroke: m.
        relief_pressure: Pa.  pump_flow: flow available to this circuit, m³/s.
        barrel_mass, rod_mass: kg for the whole circuit.
    """

    bore: float
    rod_diameter: float
    closed_length: float
    stroke: float
    relief_pressure: float
    pump_flow: float
    barrel_mass: float
    rod_mass: float
    count: int = 1

    def __post_init__(self) -> None:
        if not 0 < self.rod_diameter < self.bore:
            raise ValueError(f"cylinder rod diameter must be in (0, bore={self.bore}), got {self.rod_diameter}")
        for name in ("closed_length", "stroke", "relief_pressure", "pump_flow", "barrel_mass", "rod_mass"):
            if not getattr(self, name) > 0:
                raise ValueError(f"CylinderSpec.{name} must be > 0, got {getattr(self, name)}")

    @property
    def bore_area(self) -> float:
        """Piston area of all cylinders, m²."""
        return self.count * math.pi * self.bore**2 / 4

    @property
    def annulus_area(self) -> float:
        """Rod-side area of all cylinders, m²."""
        return self.count * math.pi * (self.bore**2 - self.rod_diameter**2) / 4

    @property
    def max_extend_force(self) -> float:
        """Relief pressure × piston area, N."""
        return self.relief_pressure * self.bore_area

    @property
    def max_retract_force(self) -> float:
        """Relief pressure × annulus area, N (pulling)."""
        return self.relief_pressure * self.annulus_area

    @property
    def extend_speed(self) -> float:
        """Flow-limited extension speed, m/s."""
        return self.pump_flow / self.bore_area

    @property
    def retract_speed(self) -> float:
        """Flow-limited retraction speed (faster: smaller area), m/s."""
        return self.pump_flow / self.annulus_area

    def scaled(self, f: Mapping[str, float]) -> CylinderSpec:
        bore_area_factor = f["bore"] ** 2
        return replace(
            self,
            bore=self.bore * f["bore"],
            rod_diameter=self.rod_diameter * f["bore"],
            closed_length=self.closed_length * f["length"],
            stroke=self.stroke * f["length"],
            relief_pressure=self.relief_pressure * f["pressure"],
            pump_flow=self.pump_flow * f["cylinder_speed"] * bore_area_factor,
            barrel_mass=self.barrel_mass * f["mass"],
            rod_mass=self.rod_mass * f["mass"],
        )


@dataclass(frozen=True)
class MassProperties:
    """Body masses, kg. ``bucket`` includes the bucket base (Table 2 lists them apart)."""

    bucket: float
    link_b: float
    bell_crank: float
    boom: float
    chassis: float  # frame, cab, axles, counterweight: operating mass minus the linkage

    def scaled(self, mass: float) -> MassProperties:
        return MassProperties(**{k: v * mass for k, v in asdict(self).items()})


@dataclass(frozen=True)
class LoaderSpec:
    """A complete wheel loader: geometry, masses, hydraulics, drive and ratings.

    Attributes:
        name: preset name or a description of how it was derived.
        scale: length ratio λ relative to the ER12 (1.0 for the ER12).
        travel_speed: top digging speed, m/s.  traction_coefficient: rimpull / weight.
        rated_load: kg.  provenance: where each value comes from.
    """

    name: str
    scale: float
    geometry: LinkageGeometry
    masses: MassProperties
    lift: CylinderSpec
    tilt: CylinderSpec
    travel_speed: float
    traction_coefficient: float
    rated_load: float
    provenance: Mapping[str, str] = field(default_factory=dict, compare=False)

    @property
    def linkage_mass(self) -> float:
        m = self.masses
        cyl = self.lift.barrel_mass + self.lift.rod_mass + self.tilt.barrel_mass + self.tilt.rod_mass
        return m.bucket + m.link_b + m.bell_crank + m.boom + cyl

    @property
    def operating_mass(self) -> float:
        """kg."""
        return self.masses.chassis + self.linkage_mass

    @property
    def weight(self) -> float:
        """Operating weight, N."""
        return self.operating_mass * GRAVITY

    @property
    def characteristic_length(self) -> float:
        """Boom length (pivot to O), m."""
        return self.geometry.boom_length

    @property
    def froude_time(self) -> float:
        """sqrt(L/g), s: the time unit of dimensionless observations."""
        return math.sqrt(self.characteristic_length / GRAVITY)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["provenance"] = dict(self.provenance)
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> LoaderSpec:
        try:
            g = {k: tuple(v) if isinstance(v, list | tuple) else float(v) for k, v in d["geometry"].items()}
            return cls(
                name=str(d["name"]), scale=float(d["scale"]), geometry=LinkageGeometry(**g),
                masses=MassProperties(**d["masses"]), lift=CylinderSpec(**d["lift"]), tilt=CylinderSpec(**d["tilt"]),
                travel_speed=float(d["travel_speed"]), traction_coefficient=float(d["traction_coefficient"]),
                rated_load=float(d["rated_load"]), provenance=dict(d.get("provenance", {})),
            )
        except (KeyError, TypeError) as exc:
            raise ValueError(f"not a valid LoaderSpec dictionary: {exc}") from exc


def scale_spec(base: LoaderSpec, f: Mapping[str, float], name: str, scale: float) -> LoaderSpec:
    """Apply multiplicative factors (keys of :func:`ScalingLaw.factors`) to a spec."""
    return LoaderSpec(
        name=name, scale=scale,
        geometry=base.geometry.scaled(f["length"], f["bucket_size"]),
        masses=base.masses.scaled(f["mass"]),
        lift=base.lift.scaled(f), tilt=base.tilt.scaled(f),
        travel_speed=base.travel_speed * f["travel_speed"],
        traction_coefficient=base.traction_coefficient * f["traction"],
        rated_load=base.rated_load * f["mass"] * f["bucket_size"] ** 3,
        provenance={**base.provenance, "scaling": name},
    )
