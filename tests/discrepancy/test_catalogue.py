"""The catalogue, dimensionless groups and planting (no simulation)."""

from __future__ import annotations

import pytest

from discrepancy import CATALOGUE, EFFECT_NAMES, Effect, Scales
from discrepancy.effects import JOINTS, pi_unit
from discrepancy.twin.plant import apply_sensors, plan
from scaletwin_envs.specs import make_loader, make_soil

BRIEF = ("coulomb_friction", "viscous_damping", "backlash", "actuator_delay", "hydraulic_compliance",
         "payload_mass_error", "payload_com_offset", "soil_cohesion", "soil_adhesion", "sensor_bias", "sensor_gain",
         "sensor_delay")


def test_names_and_targets() -> None:
    assert set(EFFECT_NAMES) == set(BRIEF)
    assert set(CATALOGUE["coulomb_friction"].targets) == set(JOINTS)
    assert "lift_cylinder" in CATALOGUE["actuator_delay"].targets
    assert set(CATALOGUE["backlash"].targets) == {"pin_O", "pin_21"}
    for spec in CATALOGUE.values():
        assert spec.form and spec.params and spec.plant
        for p in spec.params:
            lo, hi = p.bounds
            assert all(lo <= g <= hi for g in p.grid), (spec.name, p.name)


@pytest.mark.parametrize("scale", ["mini", "er12", "wa475"])
def test_dimensionless_round_trip(scale: str) -> None:
    scales = Scales.of(make_loader(scale), make_soil("gravel"), {"F21": 1000.0})
    e = Effect.from_pi("coulomb_friction", "boom_hinge", {"friction": 0.01}, scales)
    assert e.to_pi(scales)["friction"] == pytest.approx(0.01)
    assert e.params["friction"] == pytest.approx(0.01 * pi_unit("coulomb_friction", "friction", "boom_hinge", scales))


def test_plan_maps_every_effect() -> None:
    soil = make_soil("gravel")
    effects = [Effect.make("coulomb_friction", "lift_cylinder", {"friction": 10.0}),
               Effect.make("actuator_delay", "tilt_cylinder", {"delay": 0.1}),
               Effect.make("backlash", "pin_21", {"clearance": 0.003}),
               Effect.make("hydraulic_compliance", "lift_cylinder", {"compliance": 1e-7}),
               Effect.make("payload_mass_error", "payload", {"mass_error": 0.2}),
               Effect.make("soil_cohesion", "soil", {"cohesion": 5e3}),
               Effect.make("sensor_bias", "F21", {"bias": 3.0})]
    p = plan(effects, soil)
    assert p.physics.frictionloss == {"lift_cylinder": 10.0} and p.physics.delay == {"tilt": 0.1}
    assert p.structure.play_pins == ("pin_21",) and p.structure.compliant == ("lift",)
    assert p.physics.payload_mass_factor == pytest.approx(1.2) and p.physics.soil.cohesion == 5e3
    import numpy as np

    out = apply_sensors({"F21": np.zeros(4)}, np.arange(4.0), p.sensors)
    assert np.all(out["F21"] == 3.0)


def test_invalid_effects_are_rejected() -> None:
    with pytest.raises(ValueError, match="unknown effect"):
        Effect.make("magic", None, {})
    with pytest.raises(ValueError, match="acts on"):
        Effect.make("backlash", "boom_hinge", {"clearance": 1e-3})
