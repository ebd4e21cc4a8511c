"""The cylinders' velocity servo and relief valve as a bounded constraint (``scaletwin_envs.builder.SERVO_KINDS``).

The servo is a friction-loss constraint on the relief tendon (slide − supply, the supply a velocity source at the
commanded speed), softened so that unclamped it is the velocity servo of gain ``servo_gain`` integrated implicitly,
and bounded by the relief forces inside MuJoCo's constraint solve. The legacy force-limited velocity actuator,
integrated explicitly while clamped, relays between its limits at large timestep / servo time constant ratios; the
mini's Froude step (ratio 54) is the worst preset.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from scaletwin_envs.builder import (
    BuildOptions,
    build_model,
    froude_timestep,
    servo_gain,
    servo_time_constant,
    supply_dofs,
)
from scaletwin_envs.signals import SignalReader
from scaletwin_envs.specs import make_loader


def _tilt_run(servo: str, load: float, speed: float, kick: float | None, steps: int = 400
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The mini at its Froude step from the reset pose, the tilt commanded at ``speed`` (m/s) against a constant
    ``load`` (N) on its slide; halfway, the slide's speed is set to ``kick`` (m/s, None: not), outside the servo's
    unclamped band. Per physics step after the first five: the servo's force on the slide (N), the slide's speed
    and the speed the servo holds it to (the supply's plus its offset; m/s); and the ratio timestep / tilt-servo
    time constant."""
    spec = make_loader("mini")
    model = build_model(spec, BuildOptions.for_spec(spec, timestep=froude_timestep(spec), servo=servo))
    data = mujoco.MjData(model)
    reader = SignalReader(model, {k: (getattr(spec, k).bore_area, getattr(spec, k).annulus_area)
                                  for k in ("lift", "tilt")}, spec.weight)
    dof = int(model.joint("tilt_cylinder").dofadr[0])
    mujoco.mj_forward(model, data)
    data.ctrl[1] = speed
    for supply, shift in supply_dofs(model, spec)[1:]:
        data.qvel[supply] = speed - shift
    data.qfrc_applied[dof] = load
    supply = supply_dofs(model, spec)[1:]
    force, vel, ref = [], [], []
    for k in range(steps):
        if k == steps // 2 and kick is not None:
            data.qvel[dof] = kick
        mujoco.mj_step(model, data)
        mujoco.mj_forward(model, data)
        force.append(reader.servo_force(data, "tilt"))
        vel.append(float(data.qvel[dof]))
        ref.append(sum(float(data.qvel[s]) + shift for s, shift in supply) if supply else speed)
    ratio = model.opt.timestep / servo_time_constant(spec, "tilt")
    return np.array(force[5:]), np.array(vel[5:]), np.array(ref[5:]), ratio


def _flips(force: np.ndarray, lo: float, hi: float) -> int:
    """Physics steps on which the force jumps from one relief limit straight to the other (the relay)."""
    at_hi, at_lo = np.isclose(force, hi, rtol=1e-6), np.isclose(force, lo, rtol=1e-6)
    return int(np.sum(at_hi[1:] & at_lo[:-1]) + np.sum(at_lo[1:] & at_hi[:-1]))


def test_overrun_cylinder_holds_its_relief_force_without_chatter() -> None:
    """Commanded to extend against twice its extend relief force (the tilt stalled in the pile and pushed back),
    the cylinder gives way at exactly its relief force on every physics step; pulled by 30 % more than its retract
    relief force with the valve closed, at exactly that one. The timestep is 54 servo time constants."""
    tilt = make_loader("mini").tilt
    force, vel, _, ratio = _tilt_run("constraint", -2.0 * tilt.max_extend_force, tilt.extend_speed, None, 200)
    assert ratio > 50
    assert np.all(vel < 0)  # overrun: it retracts
    assert force == pytest.approx(np.full_like(force, tilt.max_extend_force), rel=1e-9)
    force, vel, _, _ = _tilt_run("constraint", 1.3 * tilt.max_retract_force, 0.0, None, 200)
    assert np.all(vel > 0)
    assert force == pytest.approx(np.full_like(force, -tilt.max_retract_force), rel=1e-9)


def test_held_cylinder_recovers_from_a_kick_without_a_relay() -> None:
    """Holding half its extend relief force with the valve closed, the slide kicked to 30 % of its rated speed:
    the constraint servo brakes at relief and settles back to the holding force, never jumping between its two
    relief limits, and off the limits its force is the velocity servo's, kv × (commanded − slide speed) (to 0.1 %
    of relief: the force is read after the step, from the next solve, as the env reads it). The legacy
    force-limited actuator, integrated explicitly while clamped, jumps between them (14 times here, 2026-11-26)."""
    tilt = make_loader("mini").tilt
    lo, hi = -tilt.max_retract_force, tilt.max_extend_force
    load, kick = -0.5 * tilt.max_extend_force, 0.3 * tilt.extend_speed
    force, vel, ref, _ = _tilt_run("constraint", load, 0.0, kick)
    assert _flips(force, lo, hi) == 0
    inside = (force > lo * (1 - 1e-6)) & (force < hi * (1 - 1e-6))
    assert inside.mean() > 0.9
    steady = inside.copy()
    steady[len(force) // 2 - 8:len(force) // 2 + 8] = False  # the kick's own steps: the read lags it by one
    assert force[steady] == pytest.approx(servo_gain(tilt) * (ref - vel)[steady], abs=1e-3 * hi)
    assert np.ptp(force[-50:]) < 0.01 * hi  # settled (the linkage still creeps), no chatter
    legacy, _, _, _ = _tilt_run("actuator", load, 0.0, kick)
    assert _flips(legacy, lo, hi) >= 5


@pytest.mark.parametrize("scale", ["mini", "er12", "wa475"])
def test_relief_constraint_has_the_servo_gain(scale: str) -> None:
    """The relief rows' regulariser is 1 / (kv dt), their reference acceleration −v / dt: the velocity servo of
    gain ``servo_gain`` (:func:`scaletwin_envs.builder.tune_relief`), at the default and at a halved timestep."""
    spec = make_loader(scale)
    for timestep in (None, 0.5 * froude_timestep(spec)):
        model = build_model(spec, BuildOptions.for_spec(spec, timestep=timestep))
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        dt = model.opt.timestep
        for which in ("lift", "tilt"):
            t = model.tendon(f"{which}_relief").id
            row = np.nonzero((data.efc_type == mujoco.mjtConstraint.mjCNSTR_FRICTION_TENDON) & (data.efc_id == t))[0]
            assert row.size == 1
            assert data.efc_R[row[0]] == pytest.approx(1.0 / (servo_gain(getattr(spec, which)) * dt), rel=1e-9)
            assert data.efc_KBIP[row[0], 1] == pytest.approx(1.0 / dt, rel=1e-12)


def test_default_timestep_is_the_froude_step() -> None:
    """No preset divides its Froude step any more (the mini did, into 3, for the legacy servo's relay)."""
    for scale in ("mini", "er12", "wa475"):
        spec = make_loader(scale)
        assert BuildOptions.for_spec(spec).timestep == froude_timestep(spec)
        assert BuildOptions.for_spec(spec, servo="actuator").timestep == froude_timestep(spec) / (
            3 if scale == "mini" else 1)
    with pytest.raises(ValueError, match="servo"):
        BuildOptions.for_spec(make_loader("er12"), servo="relay")
