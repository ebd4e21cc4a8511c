"""Planting effects into a twin: one strategy per kind of plant (model edit, actuator model, structure, payload,
soil, sensor model).

:func:`plan` turns a list of :class:`~discrepancy.effects.Effect` into what the twin needs: a
:class:`~discrepancy.twin.env.Structure` (built into the MuJoCo model), :class:`~discrepancy.twin.env.PhysicsParams`
(set at run time) and the sensor effects, which :func:`apply_sensors` applies to recorded signals afterwards.
The benchmark plants hidden physics this way, and the diagnosis uses the same code to model what it found.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from discrepancy.effects import Effect
from discrepancy.twin.env import PhysicsParams, Structure
from scaletwin_envs.specs.soil import SoilSpec


@dataclass
class Plan:
    """What a twin needs to include a set of effects."""

    structure: Structure = field(default_factory=Structure)
    physics: PhysicsParams = field(default_factory=PhysicsParams)
    sensors: list[Effect] = field(default_factory=list)


class Planter(Protocol):
    """Adds one effect to a :class:`Plan` (``soil`` is the twin's soil before any soil effect)."""

    def __call__(self, effect: Effect, plan: Plan, soil: SoilSpec) -> None: ...


def _add(table: dict[str, float], key: str, value: float) -> None:
    table[key] = table.get(key, 0.0) + value


def _friction(effect: Effect, plan: Plan, soil: SoilSpec) -> None:
    _add(plan.physics.frictionloss, str(effect.target), max(effect.params["friction"], 0.0))


def _damping(effect: Effect, plan: Plan, soil: SoilSpec) -> None:
    _add(plan.physics.damping, str(effect.target), max(effect.params["damping"], 0.0))


def _delay(effect: Effect, plan: Plan, soil: SoilSpec) -> None:
    plan.physics.delay[str(effect.target).removesuffix("_cylinder")] = max(effect.params["delay"], 0.0)


def _backlash(effect: Effect, plan: Plan, soil: SoilSpec) -> None:
    pin = str(effect.target)
    plan.structure = Structure((*plan.structure.play_pins, pin), plan.structure.compliant)
    plan.physics.clearance[pin] = max(effect.params["clearance"], 0.0)


def _compliance(effect: Effect, plan: Plan, soil: SoilSpec) -> None:
    c = str(effect.target).removesuffix("_cylinder")
    plan.structure = Structure(plan.structure.play_pins, (*plan.structure.compliant, c))
    plan.physics.compliance[c] = max(effect.params["compliance"], 1e-15)


def _payload_mass(effect: Effect, plan: Plan, soil: SoilSpec) -> None:
    plan.physics.payload_mass_factor *= max(1.0 + effect.params["mass_error"], 0.0)


def _payload_com(effect: Effect, plan: Plan, soil: SoilSpec) -> None:
    dx, dz = plan.physics.payload_com_offset
    plan.physics.payload_com_offset = (dx + effect.params["dx"], dz + effect.params["dz"])


def _soil_term(name: str) -> Planter:
    def plant(effect: Effect, plan: Plan, soil: SoilSpec) -> None:
        base = plan.physics.soil or soil
        value = max(getattr(base, name) + effect.params[name], 0.0)
        plan.physics.soil = dataclasses.replace(base, **{name: value})
    return plant


def _sensor(effect: Effect, plan: Plan, soil: SoilSpec) -> None:
    plan.sensors.append(effect)


PLANTERS: dict[str, Planter] = {
    "coulomb_friction": _friction, "viscous_damping": _damping, "actuator_delay": _delay, "backlash": _backlash,
    "hydraulic_compliance": _compliance, "payload_mass_error": _payload_mass, "payload_com_offset": _payload_com,
    "soil_cohesion": _soil_term("cohesion"), "soil_adhesion": _soil_term("adhesion"), "sensor_bias": _sensor,
    "sensor_gain": _sensor, "sensor_delay": _sensor,
}


def plan(effects: Sequence[Effect], soil: SoilSpec, base: PhysicsParams | None = None) -> Plan:
    """The structure, run-time physics and sensor models of a twin with ``effects`` (added to ``base``)."""
    out = Plan(physics=(base or PhysicsParams()).copy())
    for effect in effects:
        PLANTERS[effect.name](effect, out, soil)
    return out


def shift(values: np.ndarray, time: np.ndarray, delay: float) -> np.ndarray:
    """``values`` delayed by ``delay`` seconds (linear interpolation; the first sample holds before the start)."""
    return np.interp(time - delay, time, values, left=values[0])


def _sensor_fault(effect: Effect, x: np.ndarray, time: np.ndarray) -> np.ndarray:
    p = effect.params
    if effect.name == "sensor_bias":
        return x + p["bias"]
    if effect.name == "sensor_gain":
        return x * (1.0 + p["gain_error"])
    return shift(x, time, max(p["delay"], 0.0))


def apply_sensors(signals: Mapping[str, np.ndarray], time: np.ndarray, sensors: Sequence[Effect]
                  ) -> dict[str, np.ndarray]:
    """Signals as faulty sensors would read them (a new dict; channels without a fault are shared).

    Raises:
        ValueError: a sensor effect on a signal that is not there.
    """
    out = dict(signals)
    for effect in sensors:
        if effect.target not in out:
            raise ValueError(f"{effect.label()}: no signal {effect.target!r} (signals: {sorted(out)})")
        out[str(effect.target)] = _sensor_fault(effect, np.asarray(out[str(effect.target)], float), time)
    return out
