"""Benchmark cases: what is planted (hidden from the tool), on which machine, soil and noise level.

Magnitudes are drawn in the effects' dimensionless groups Π (log-uniform in :data:`RANGES`, with a random sign
for signed parameters), so the same case mix is equally hard at every scale. Out-of-catalogue physics
(:data:`OUT_OF_CATALOGUE`) is planted through run-time terms the catalogue has no entry for.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from discrepancy.effects import CATALOGUE, Effect, Scales
from discrepancy.twin.env import PhysicsParams
from discrepancy.twin.spec import TwinSpec
from scaletwin_envs.specs import make_loader, make_soil

SCALES = ("mini", "er12", "wa475")
SOILS = ("gravel", "sand", "sandy_loam", "clay_loam")
NOISES = (0.005, 0.01, 0.02)
MIX = (("null", 0.15), ("single", 0.5), ("double", 0.2), ("ooc", 0.15))
#: Signals a sensor fault is planted on (channels a real machine measures directly).
SENSED = ("F21", "F31", "Pf_lift", "Pf_tilt", "p_lift", "p_tilt", "lift_extension", "tilt_extension", "boom_angle",
          "bucket_pitch", "travel_speed", "F21_x", "F31_z")
#: Planted magnitude range in Π per (effect, parameter); signed parameters get a random sign.
RANGES: dict[tuple[str, str], tuple[float, float, bool]] = {
    ("coulomb_friction", "friction"): (0.003, 0.012, False),
    ("viscous_damping", "damping"): (0.01, 0.05, False),
    ("backlash", "clearance"): (0.001, 0.004, False),
    ("actuator_delay", "delay"): (0.08, 0.4, False),
    ("hydraulic_compliance", "compliance"): (0.004, 0.02, False),
    ("payload_mass_error", "mass_error"): (0.08, 0.3, True),
    ("payload_com_offset", "dx"): (0.02, 0.06, True),
    ("payload_com_offset", "dz"): (0.02, 0.06, True),
    ("soil_cohesion", "cohesion"): (0.02, 0.08, False),
    ("soil_adhesion", "adhesion"): (0.02, 0.08, False),
    ("sensor_bias", "bias"): (0.05, 0.25, True),
    ("sensor_gain", "gain_error"): (0.04, 0.2, True),
    ("sensor_delay", "delay"): (0.1, 0.5, False),
}
OUT_OF_CATALOGUE = ("boom_spring", "edge_drag_v2", "soft_tilt_servo")


@dataclass(frozen=True)
class Case:
    """One benchmark case (all seeds fixed): the twin, the hidden physics and the noise."""

    index: int
    kind: str
    twin: TwinSpec
    noise: float
    planted: tuple[tuple[str, str, tuple[tuple[str, float], ...]], ...] = ()  # (effect, target, ((param, Π), ...))
    ooc: str | None = None
    ooc_size: float = 0.0
    held_out_seed: int = 0
    meta: dict[str, str] = field(default_factory=dict, compare=False)

    def effects(self, scales: Scales) -> list[Effect]:
        """The planted effects in SI for ``scales`` (sensor faults are relative to each signal's spread; a soil
        term is raised to 10–40 % of the soil's own term when that is larger, or it would not show)."""
        out = []
        for name, target, pis in self.planted:
            values = dict(pis)
            if name in ("soil_cohesion", "soil_adhesion"):
                key = name.removeprefix("soil_")
                own = getattr(scales, key) / (scales.unit_weight * scales.length)
                lo, hi, _ = RANGES[(name, key)]
                values[key] = max(values[key], own * (0.1 + 0.3 * (values[key] - lo) / (hi - lo)))
            out.append(Effect.from_pi(name, target, values, scales))
        return out

    def extra(self) -> PhysicsParams:
        """Out-of-catalogue run-time physics (nothing for catalogue cases)."""
        return ooc_physics(self.ooc, self.ooc_size, self.twin) if self.ooc else PhysicsParams()


def ooc_physics(name: str, size: float, twin: TwinSpec) -> PhysicsParams:
    """An out-of-catalogue term of relative size ``size``: a torsional spring in the boom hinge, a velocity-squared
    drag on the cutting edge in the pile (soil-stiffness-like), or a tilt valve with a softer pressure–flow gain."""
    loader = twin.loader
    f_lift, length = loader.lift.max_extend_force, loader.characteristic_length
    if name == "boom_spring":
        return PhysicsParams(stiffness={"boom_hinge": size * f_lift * length})
    if name == "edge_drag_v2":
        return PhysicsParams(edge_drag=size * f_lift / loader.travel_speed**2)
    if name == "soft_tilt_servo":
        return PhysicsParams(servo_gain={"tilt": size})
    raise ValueError(f"unknown out-of-catalogue effect {name!r}; known {OUT_OF_CATALOGUE}")


OOC_RANGES = {"boom_spring": (0.05, 0.2), "edge_drag_v2": (0.1, 0.4), "soft_tilt_servo": (0.01, 0.05)}


def _magnitude(rng: np.random.Generator, key: tuple[str, str]) -> float:
    lo, hi, signed = RANGES[key]
    value = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    return value * (rng.choice((-1.0, 1.0)) if signed else 1.0)


def random_effect(rng: np.random.Generator, exclude: set[str] = frozenset()
                  ) -> tuple[str, str, tuple[tuple[str, float], ...]]:
    """A catalogue effect at a random target and magnitude Π (not one of ``exclude``)."""
    name = str(rng.choice([n for n in CATALOGUE if n not in exclude]))
    spec = CATALOGUE[name]
    target = str(rng.choice(SENSED)) if spec.target_kind == "signal" else str(rng.choice(spec.targets))
    return name, target, tuple((p.name, _magnitude(rng, (name, p.name))) for p in spec.params)


def make_case(index: int, seed: int, kind: str | None = None) -> Case:
    """Case ``index`` of the benchmark with master seed ``seed`` (kind drawn from :data:`MIX` unless given)."""
    rng = np.random.default_rng([seed, index])
    kinds, weights = zip(*MIX, strict=True)
    kind = kind or str(rng.choice(kinds, p=np.asarray(weights) / sum(weights)))
    scale, soil = str(rng.choice(SCALES)), str(rng.choice(SOILS))
    twin = TwinSpec(make_loader(scale), make_soil(soil), {}, int(rng.integers(1, 10_000)))
    noise = float(rng.choice(NOISES))
    effects: list[tuple[str, str, tuple[tuple[str, float], ...]]] = []
    ooc, size = None, 0.0
    if kind in ("single", "double"):
        effects.append(random_effect(rng))
    if kind == "double":
        effects.append(random_effect(rng, exclude={effects[0][0]}))
    if kind == "ooc":
        ooc = str(rng.choice(OUT_OF_CATALOGUE))
        lo, hi = OOC_RANGES[ooc]
        size = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    return Case(index, kind, twin, noise, tuple(effects), ooc, size, twin.seed + 5000,
                {"scale": scale, "soil": soil})


def make_cases(n: int, seed: int) -> list[Case]:
    """``n`` cases; the kinds follow :data:`MIX` in a fixed interleaved order so small ``n`` still mixes them."""
    order = ["single", "null", "double", "single", "ooc", "single", "double", "single", "null", "single",
             "ooc", "single", "double", "single", "single", "null", "double", "ooc", "single", "single"]
    return [make_case(i, seed, order[i % len(order)]) for i in range(n)]
