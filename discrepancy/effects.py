"""The catalogue: effects a wheel-loader twin typically leaves out, with physical form, parameters and groups.

Each :class:`EffectSpec` says what the effect is (its physical law), what it acts on (``target_kind`` and the
targets, named as in the MuJoCo model or the signal list), how it is planted in a twin (``plant``: a model edit,
an actuator model, the payload, the soil or a sensor model; see :mod:`discrepancy.twin.plant`), its parameters with SI
units, where it shows (signals and dig phases), and the dimensionless group of each parameter, so that a fitted
effect carries to a machine of another size (:class:`Scales` converts between SI and the group).

Parameters are searched and fitted in their dimensionless form Π; :attr:`ParamSpec.grid` are the magnitudes the
screening tries, :attr:`ParamSpec.bounds` the admissible range.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from scaletwin_envs.specs.loader import LoaderSpec
from scaletwin_envs.specs.soil import SoilSpec

HINGES = ("boom_hinge", "bucket_hinge", "bell_crank_hinge", "link_b_hinge", "lift_barrel_hinge", "tilt_barrel_hinge")
CYLINDER_JOINTS = ("lift_cylinder", "tilt_cylinder")
JOINTS = HINGES + CYLINDER_JOINTS
PINS = ("pin_O", "pin_21")
FORCES = ("F21", "F31", "F21_x", "F21_z", "F31_x", "F31_z", "Pf_lift", "Pf_tilt", "p_lift", "p_tilt")
MOTION = ("lift_extension", "tilt_extension", "lift_speed", "tilt_speed", "travel_speed", "boom_angle",
          "bucket_pitch", "a1", "alpha1", "V1", "w1")
ALL_PHASES = ("approach", "penetrate", "curl", "lift", "pull_back")
DIG = ("penetrate", "curl")


@dataclass(frozen=True)
class Scales:
    """Reference quantities of one machine and soil that make effect parameters dimensionless (SI).

    Attributes:
        length: boom length L, m.  froude_time: √(L/g), s.
        relief_force: cylinder → relief pressure × piston area, N.  stroke: cylinder → m.
        speed: cylinder → flow-limited extension speed, m/s.  unit_weight: soil γ, N/m³.
        cohesion, adhesion: the twin soil's c and c_a, Pa.  signal_scale: signal → typical spread (SI).
    """

    length: float
    froude_time: float
    relief_force: Mapping[str, float]
    stroke: Mapping[str, float]
    speed: Mapping[str, float]
    unit_weight: float
    cohesion: float = 0.0
    adhesion: float = 0.0
    signal_scale: Mapping[str, float] = field(default_factory=dict)

    @classmethod
    def of(cls, loader: LoaderSpec, soil: SoilSpec, signal_scale: Mapping[str, float] | None = None) -> Scales:
        cyl = {"lift_cylinder": loader.lift, "tilt_cylinder": loader.tilt}
        return cls(
            length=loader.characteristic_length, froude_time=loader.froude_time,
            relief_force={k: c.max_extend_force for k, c in cyl.items()},
            stroke={k: c.stroke for k, c in cyl.items()}, speed={k: c.extend_speed for k, c in cyl.items()},
            unit_weight=soil.unit_weight, cohesion=soil.cohesion, adhesion=soil.adhesion,
            signal_scale=dict(signal_scale or {}),
        )


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: SI ``name``/``unit``; ``group`` names its dimensionless form Π; ``bounds``/``grid`` in Π."""

    name: str
    unit: str
    group: str
    bounds: tuple[float, float]
    grid: tuple[float, ...]
    log: bool = True  # searched on a log scale (positive parameters)


@dataclass(frozen=True)
class EffectSpec:
    """A catalogue entry (see module docstring)."""

    name: str
    target_kind: str  # "joint", "cylinder", "pin", "signal", "payload" or "soil"
    targets: tuple[str, ...]
    form: str
    plant: str  # "model", "actuator", "structure", "payload", "soil" or "sensor"
    params: tuple[ParamSpec, ...]
    signals: tuple[str, ...]
    phases: tuple[str, ...]

    def unit(self, param: str, target: str | None) -> str:
        """SI unit of a parameter for a target (a hinge takes a torque where a slide takes a force)."""
        unit = next(p.unit for p in self.params if p.name == param)
        return HINGE_UNITS.get(unit, unit) if target in HINGES else unit


HINGE_UNITS = {"N": "N*m", "N*s/m": "N*m*s/rad"}


def _friction_scale(target: str, s: Scales) -> float:
    """Relief force of the cylinder (its own circuit), or lift relief force × L for a hinge."""
    return s.relief_force[target] if target in CYLINDER_JOINTS else s.relief_force["lift_cylinder"] * s.length


def _damping_scale(target: str, s: Scales) -> float:
    v = s.speed.get(target, s.speed["lift_cylinder"])
    return _friction_scale(target, s) / (v / s.length if target in HINGES else v)


def _cyl(target: str) -> str:
    return target if target in CYLINDER_JOINTS else f"{target}_cylinder"


#: SI value of one unit of Π, by (effect, parameter): a function of the target and the scales.
_UNIT_OF_PI = {
    ("coulomb_friction", "friction"): _friction_scale,
    ("viscous_damping", "damping"): _damping_scale,
    ("backlash", "clearance"): lambda t, s: s.length,
    ("actuator_delay", "delay"): lambda t, s: s.froude_time,
    ("hydraulic_compliance", "compliance"): lambda t, s: s.stroke[_cyl(t)] / s.relief_force[_cyl(t)],
    ("payload_mass_error", "mass_error"): lambda t, s: 1.0,
    ("payload_com_offset", "dx"): lambda t, s: s.length,
    ("payload_com_offset", "dz"): lambda t, s: s.length,
    ("soil_cohesion", "cohesion"): lambda t, s: s.unit_weight * s.length,
    ("soil_adhesion", "adhesion"): lambda t, s: s.unit_weight * s.length,
    ("sensor_bias", "bias"): lambda t, s: s.signal_scale.get(t, 1.0),
    ("sensor_gain", "gain_error"): lambda t, s: 1.0,
    ("sensor_delay", "delay"): lambda t, s: s.froude_time,
}


def pi_unit(effect: str, param: str, target: str | None, scales: Scales) -> float:
    """SI value of Π = 1 for ``param`` of ``effect`` at ``target``."""
    return float(_UNIT_OF_PI[(effect, param)](target, scales))


def _p(name: str, unit: str, group: str, bounds: tuple[float, float], grid: tuple[float, ...], log: bool = True
       ) -> ParamSpec:
    return ParamSpec(name, unit, group, bounds, grid, log)


CATALOGUE: dict[str, EffectSpec] = {e.name: e for e in (
    EffectSpec("coulomb_friction", "joint", JOINTS,
               "dry friction F = -F_c sign(v) in a hinge or a cylinder (seals): force residual steps at velocity "
               "reversals, the servo pushes F_c harder", "model",
               (_p("friction", "N", "F_c/F_relief [cylinder], T_c/(F_relief,lift L) [hinge]", (2e-5, 0.1),
                   (0.0015, 0.008)),),
               ("Pf_lift", "Pf_tilt", "p_lift", "p_tilt", "F21", "F31"), ALL_PHASES),
    EffectSpec("viscous_damping", "joint", JOINTS,
               "viscous loss F = -b v in a hinge or a cylinder: force residual proportional to speed", "model",
               (_p("damping", "N*s/m", "b v_ext/F_relief [cylinder], b (v_ext/L)/(F_relief,lift L) [hinge]",
                   (2e-5, 0.5), (0.002, 0.012)),),
               ("Pf_lift", "Pf_tilt", "p_lift", "p_tilt", "lift_speed", "tilt_speed"), ALL_PHASES),
    EffectSpec("backlash", "pin", PINS,
               "radial clearance at a pin: a dead zone at load reversal, the linkage shifts by the clearance and "
               "closes it with a force spike", "structure",
               (_p("clearance", "m", "c/L", (1e-5, 0.02), (0.001, 0.004)),),
               ("F21", "F31", "Pf_tilt", "bucket_pitch", "a1", "alpha1"), ALL_PHASES),
    EffectSpec("actuator_delay", "cylinder", CYLINDER_JOINTS,
               "valve or control dead time: every signal driven by the cylinder is shifted by the same delay",
               "actuator", (_p("delay", "s", "tau/sqrt(L/g)", (1e-3, 1.2), (0.05, 0.15, 0.4)),),
               ("lift_extension", "tilt_extension", "lift_speed", "tilt_speed", "boom_angle", "bucket_pitch"),
               ALL_PHASES),
    EffectSpec("hydraulic_compliance", "cylinder", CYLINDER_JOINTS,
               "compressible oil column (bulk modulus, hose volume): a spring k = beta A^2 / V between the valve "
               "flow and the rod; lag and ringing between cylinder force and motion", "structure",
               (_p("compliance", "m/N", "C F_relief/stroke", (1e-4, 0.1), (0.003, 0.006, 0.012, 0.024)),),
               ("Pf_lift", "Pf_tilt", "lift_speed", "tilt_speed", "w1", "alpha1"), ALL_PHASES),
    EffectSpec("payload_mass_error", "payload", ("payload",),
               "the load is heavier or lighter than volume x density: pin-force residual proportional to (g + a) "
               "while carrying", "payload",
               (_p("mass_error", "1", "m_true/m_twin - 1", (-0.6, 1.5), (-0.15, 0.15), log=False),),
               ("m_b", "F21", "F31", "Pf_lift", "Pf_tilt", "x_b", "y_b"), ("curl", "lift", "pull_back")),
    EffectSpec("payload_com_offset", "payload", ("payload",),
               "the load's centre of mass is offset by (dx, dz) in the bucket frame: residual moment "
               "m g dr cos(pitch)", "payload",
               (_p("dx", "m", "dx/L", (-0.15, 0.15), (-0.03, 0.03), log=False),
                _p("dz", "m", "dz/L", (-0.15, 0.15), (-0.03, 0.03), log=False)),
               ("x_b", "y_b", "F21", "F31", "Pf_tilt"), ("curl", "lift", "pull_back")),
    EffectSpec("soil_cohesion", "soil", ("soil",),
               "cohesion c of the pile: the c d N_c term of the earthmoving equation and edge bearing, only while "
               "the edge is in the pile", "soil",
               (_p("cohesion", "Pa", "c/(gamma L)", (0.0, 0.5), (0.015, 0.06), log=False),),
               ("R_x", "R_z", "F31", "Pf_lift", "travel_speed"), DIG),
    EffectSpec("soil_adhesion", "soil", ("soil",),
               "soil-metal adhesion c_a: the c_a d N_ca term on the blade and adhesion on the side plates; material "
               "clings to the bucket", "soil",
               (_p("adhesion", "Pa", "c_a/(gamma L)", (0.0, 0.5), (0.015, 0.06), log=False),),
               ("R_x", "R_z", "F31", "Pf_lift", "travel_speed"), DIG),
    EffectSpec("sensor_bias", "signal", (), "constant offset y = x + b on one channel; its redundant partners "
               "(components, pressure, route 2) disagree", "sensor",
               (_p("bias", "signal unit", "b/spread(signal)", (-10.0, 10.0), (), log=False),), (), ALL_PHASES),
    EffectSpec("sensor_gain", "signal", (), "scale error y = g x on one channel", "sensor",
               (_p("gain_error", "1", "g - 1", (-0.9, 5.0), (), log=False),), (), ALL_PHASES),
    EffectSpec("sensor_delay", "signal", (), "one channel lags: y(t) = x(t - d)", "sensor",
               (_p("delay", "s", "d/sqrt(L/g)", (0.0, 4.0), ()),), (), ALL_PHASES),
)}
EFFECT_NAMES = tuple(CATALOGUE)
UNEXPLAINED = "unexplained"


def spec(name: str) -> EffectSpec:
    """The catalogue entry ``name``.

    Raises:
        ValueError: not in the catalogue.
    """
    if name not in CATALOGUE:
        raise ValueError(f"unknown effect {name!r}; the catalogue has {list(CATALOGUE)}")
    return CATALOGUE[name]


@dataclass(frozen=True)
class Effect:
    """One effect instance: catalogue ``name``, ``target`` and parameter values (SI, by parameter name)."""

    name: str
    target: str | None
    values: tuple[tuple[str, float], ...]

    @classmethod
    def make(cls, name: str, target: str | None, values: Mapping[str, float]) -> Effect:
        """Validated constructor (known effect, known parameters, a valid target for non-signal targets)."""
        s = spec(name)
        names = [p.name for p in s.params]
        if sorted(values) != sorted(names):
            raise ValueError(f"{name} takes parameters {names}, got {sorted(values)}")
        if s.targets and target not in s.targets:
            raise ValueError(f"{name} acts on {list(s.targets)}, got target {target!r}")
        return cls(name, target, tuple((k, float(values[k])) for k in names))

    @property
    def params(self) -> dict[str, float]:
        return dict(self.values)

    @property
    def spec(self) -> EffectSpec:
        return spec(self.name)

    def to_pi(self, scales: Scales) -> dict[str, float]:
        """Each parameter as its dimensionless group Π."""
        return {k: v / pi_unit(self.name, k, self.target, scales) for k, v in self.values}

    @classmethod
    def from_pi(cls, name: str, target: str | None, pis: Mapping[str, float], scales: Scales) -> Effect:
        return cls.make(name, target, {k: v * pi_unit(name, k, target, scales) for k, v in pis.items()})

    def label(self) -> str:
        return f"{self.name}[{self.target}]" if self.target else self.name


def pi_is_finite(values: Mapping[str, float]) -> bool:
    return all(math.isfinite(v) for v in values.values())
