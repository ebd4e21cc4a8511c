"""The dig env with hooks for physics a twin may leave out (the env itself is not modified).

:class:`TwinDigEnv` subclasses :class:`~scaletwin_envs.envs.wheel_loader_dig.WheelLoaderDigEnv` and adds

* structural options (:class:`Structure`), applied to the :class:`mujoco.MjSpec` before compiling: clearance
  joints at a pin (backlash), a compliant oil column in a cylinder (an integrated-velocity servo acting through
  a spring), and a command history on both cylinder actuators so that a valve delay can be set at run time;
* run-time parameters (:class:`PhysicsParams`), written into the compiled model or the dig model before each
  reset: joint Coulomb friction and viscous damping, valve delays, pin clearances, oil-column compliances, the
  payload's mass factor and centre-of-mass offset, and the soil.

With no structure and default parameters the env reproduces ``WheelLoaderDig-v1`` built with the legacy actuator
servo exactly (tested; the registered env uses the constraint servo, see :class:`TwinDigEnv`).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

from scaletwin_envs.builder import build_spec
from scaletwin_envs.envs.wheel_loader_dig import WheelLoaderDigEnv
from scaletwin_envs.specs.soil import SoilSpec

CYLINDERS = ("lift", "tilt")
PINS = ("pin_O", "pin_21")
MAX_DELAY = 0.6  # s: command history kept on each cylinder actuator (the largest valve delay that can be set)
SETTLE_TIME = 1.0  # s of settling after reset for a compliant oil column (pressure builds up to hold the load)


@dataclass(frozen=True)
class Structure:
    """Model structure beyond the nominal twin: pins with clearance joints, cylinders with a compliant oil column."""

    play_pins: tuple[str, ...] = ()
    compliant: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name, allowed in (("play_pins", PINS), ("compliant", CYLINDERS)):
            bad = sorted(set(getattr(self, name)) - set(allowed))
            if bad:
                raise ValueError(f"Structure.{name}: unknown {bad}; allowed {list(allowed)}")
            object.__setattr__(self, name, tuple(sorted(set(getattr(self, name)))))


@dataclass
class PhysicsParams:
    """Run-time physics of the twin (SI units; every default is the nominal twin).

    Attributes:
        frictionloss: joint name → added Coulomb friction (N for slides, N·m for hinges).
        damping: joint name → added viscous damping (N·s/m for slides, N·m·s/rad for hinges).
        delay: cylinder (``lift``/``tilt``) → valve delay, s (≤ :data:`MAX_DELAY`).
        clearance: pin (``pin_O``/``pin_21``) → diametral clearance, m (needs the pin in ``Structure.play_pins``).
        compliance: cylinder → oil-column compliance, m/N (needs the cylinder in ``Structure.compliant``).
        payload_mass_factor: true load mass / the dig model's volume × density.
        payload_com_offset: (dx, dz), m, added to the load's centre of mass in the bucket frame.
        soil: the pile's soil (None: the env's own).
        stiffness: joint name → torsional/linear spring about the start pose (N·m/rad or N/m); not in the
            catalogue (used to plant out-of-catalogue physics).
        edge_drag: velocity-squared drag on the cutting edge while it is in the pile, N·s²/m²; not in the catalogue.
        servo_gain: cylinder → factor on the valve's pressure–flow gain (servo stiffness); not in the catalogue.
        jitter: relative size of a seeded perturbation of the start state and pile (0: none).
        jitter_seed: seed of that perturbation.
    """

    frictionloss: dict[str, float] = field(default_factory=dict)
    damping: dict[str, float] = field(default_factory=dict)
    delay: dict[str, float] = field(default_factory=dict)
    clearance: dict[str, float] = field(default_factory=dict)
    compliance: dict[str, float] = field(default_factory=dict)
    payload_mass_factor: float = 1.0
    payload_com_offset: tuple[float, float] = (0.0, 0.0)
    soil: SoilSpec | None = None
    stiffness: dict[str, float] = field(default_factory=dict)
    edge_drag: float = 0.0
    servo_gain: dict[str, float] = field(default_factory=dict)
    jitter: float = 0.0
    jitter_seed: int = 0

    def copy(self) -> PhysicsParams:
        """A deep copy (dictionaries are not shared)."""
        return dataclasses.replace(self, **{f.name: dict(getattr(self, f.name)) for f in dataclasses.fields(self)
                                            if isinstance(getattr(self, f.name), dict)})


class TwinDigEnv(WheelLoaderDigEnv):
    """``WheelLoaderDig-v1`` with a :class:`Structure` built in and :class:`PhysicsParams` set at run time.

    Built with the legacy actuator servo (``scaletwin_envs.builder.SERVO_KINDS``): its servo-gain, delay and
    compliance parameters edit the cylinders' force-limited velocity actuators, so it keeps them and the timestep
    rule they need (not yet ported to the env's constraint servo)."""

    SERVO = "actuator"

    def __init__(self, structure: Structure | None = None, **kwargs: Any) -> None:
        self.structure = structure or Structure()
        self.physics = PhysicsParams()
        self._written: tuple[float, np.ndarray] | None = None
        self._payload_body = -1
        #: the signals read between control steps, at each soil refresh inside one, in order (None: not read; see
        #: :meth:`read_between`)
        self.between: list[dict[str, float]] | None = None
        self._block = 0
        super().__init__(**kwargs)
        self.nominal_soil = self.soil
        self._nominal = {name: getattr(self.model, name).copy() for name in
                         ("dof_frictionloss", "dof_damping", "actuator_delay", "jnt_range", "actuator_gainprm",
                          "actuator_biasprm", "jnt_stiffness", "qpos_spring")}
        self._act_ids = {c: self.model.actuator(c).id for c in CYLINDERS}
        self._payload_body = self.model.body("payload").id

    # -- building ----------------------------------------------------------------------------------------
    def _initialize_simulation(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        spec = build_spec(self.loader, self.build_options)
        nsample = math.ceil(MAX_DELAY / self.build_options.timestep) + 2
        for c in CYLINDERS:
            spec.actuator(c).nsample = nsample
        for pin in self.structure.play_pins:
            _add_play(spec, pin, self.loader, self.build_options)
        for c in self.structure.compliant:
            _make_compliant(spec, c, self.loader)
        model = spec.compile()
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, self.width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, self.height)
        return model, mujoco.MjData(model)

    # -- run-time physics --------------------------------------------------------------------------------
    def set_physics(self, physics: PhysicsParams) -> None:
        """Use ``physics`` from the next reset on.

        Raises:
            ValueError: a joint, cylinder or pin that does not exist or lacks the structure it needs.
        """
        m = self.model
        for name, value in self._nominal.items():
            getattr(m, name)[:] = value
        for table, attr in ((physics.frictionloss, "dof_frictionloss"), (physics.damping, "dof_damping")):
            for joint, value in table.items():
                getattr(m, attr)[m.jnt_dofadr[_joint_id(m, joint)]] += float(value)
        for c, tau in physics.delay.items():
            if not 0.0 <= tau <= MAX_DELAY:
                raise ValueError(f"delay of {c!r} must be in [0, {MAX_DELAY}] s, got {tau}")
            m.actuator_delay[self._act(c)] = float(tau)
        for joint, k in physics.stiffness.items():
            jid = _joint_id(m, joint)
            m.jnt_stiffness[jid] = float(k)
        for c, factor in physics.servo_gain.items():
            a = self._act(c)
            m.actuator_gainprm[a, 0] *= factor
            m.actuator_biasprm[a, 2] *= factor
        for pin, gap in physics.clearance.items():
            self._require(pin, self.structure.play_pins, "play_pins")
            for j in _play_joints(m, pin):
                m.jnt_range[j] = (-0.5 * max(gap, 0.0), 0.5 * max(gap, 0.0))
        for c, compliance in physics.compliance.items():
            self._require(c, self.structure.compliant, "compliant")
            k = 1.0 / max(float(compliance), 1e-15)
            a = self._act(c)
            m.actuator_gainprm[a, 0], m.actuator_biasprm[a, 1] = k, -k
        self.physics = physics.copy()
        self.soil = physics.soil or self.nominal_soil

    def _act(self, cylinder: str) -> int:
        if cylinder not in self._act_ids:
            raise ValueError(f"unknown cylinder {cylinder!r}; known {list(CYLINDERS)}")
        return self._act_ids[cylinder]

    @staticmethod
    def _require(name: str, built: tuple[str, ...], what: str) -> None:
        if name not in built:
            raise ValueError(f"{name!r} needs Structure({what}=({name!r},)) when the twin is built")

    # -- hooks -------------------------------------------------------------------------------------------
    def reset_model(self) -> np.ndarray:
        self._written = None
        obs = super().reset_model()
        if self.physics.stiffness:  # springs rest at the start pose
            self.model.qpos_spring[:] = self.data.qpos
        if self.physics.jitter > 0.0:
            self._perturb(np.random.default_rng(self.physics.jitter_seed), self.physics.jitter)
        if self.structure.compliant:
            self._settle()
            self._last_obs = obs = self._get_obs()
        return obs

    def _perturb(self, rng: np.random.Generator, size: float) -> None:
        """Jitter the pile height and the boom/bucket angles by ``size`` (relative, rad)."""
        self.pile.h *= 1.0 + size * rng.standard_normal()
        self.pile.initial[:] = self.pile.h
        for name in ("boom_hinge", "bucket_hinge"):
            self.data.qpos[self.model.joint(name).qposadr[0]] += size * rng.standard_normal()
        mujoco.mj_forward(self.model, self.data)

    def _settle(self) -> None:
        """Start a compliant column at its holding pressure: pressurise at the start pose, then let it settle."""
        for c in self.structure.compliant:
            self.data.act[self._act_adr(c)] = self.data.qpos[self.model.joint(f"{c}_cylinder").qposadr[0]]
        self.data.ctrl[:] = 0.0
        steps = int(SETTLE_TIME / self.model.opt.timestep)
        for _ in range(0, steps, self.external_force_substeps):
            self._clamp_windup()
            mujoco.mj_step(self.model, self.data, nstep=self.external_force_substeps)
        self.data.time = 0.0
        mujoco.mj_forward(self.model, self.data)
        mujoco.mj_rnePostConstraint(self.model, self.data)
        self.signals = self._read_signals(self.soil_force())

    def _act_adr(self, cylinder: str) -> int:
        return int(self.model.actuator_actadr[self._act(cylinder)])

    def _clamp_windup(self) -> None:
        """Relief valve: the integrated flow reference may not run further ahead than the relief force allows."""
        for c in self.structure.compliant:
            a = self._act(c)
            k = float(self.model.actuator_gainprm[a, 0])
            q = float(self.data.qpos[self.model.joint(f"{c}_cylinder").qposadr[0]])
            lo, hi = self.model.actuator_forcerange[a]
            adr = self._act_adr(c)
            self.data.act[adr] = min(max(self.data.act[adr], q + lo / k), q + hi / k)

    def read_between(self, on: bool = True) -> None:
        """From the next step on, also read the signals inside each control step, at every soil refresh after its
        first (``external_force_substeps`` physics steps apart: 5 per control step by default), into
        :attr:`between`, cleared here. What a log sampled faster than the control step saw between the twin's
        samples (:func:`~discrepancy.data.fieldlog.resampling_operator`). Reading computes the forces of the state
        reached (``mj_forward``) and changes nothing the physics goes on from: the control-step signals are the same
        to the bit (tested)."""
        self.between = [] if on else None

    def readings(self, rows: Sequence[Mapping[str, float]]) -> tuple[float, list[Mapping[str, float]]]:
        """``rows`` (each control step's signals since the reset, in order) with the readings taken between them
        (:meth:`read_between`) in their places: the step between readings (s) and every reading in time order."""
        parts = self.frame_skip // self.external_force_substeps
        inside = iter(self.between or [])  # parts - 1 readings inside each control step, in order
        merged = [r for row in rows for r in (*itertools.islice(inside, parts - 1), row)]
        return float(self.dt) / parts, merged

    def _simulate(self, ctrl: np.ndarray) -> str | None:
        self._block = 0
        return super()._simulate(ctrl)

    def _apply_external_forces(self) -> None:
        if self.between is not None and self._block:
            mujoco.mj_forward(self.model, self.data)
            mujoco.mj_rnePostConstraint(self.model, self.data)
            self.between.append(self._step_signals(self._read_signals(self.soil_force())))
        self._block += 1
        self._clamp_windup()
        super()._apply_external_forces()
        if self.physics.edge_drag > 0.0 and self._soil_force.depth > 0.0:
            vx, vz = self._vel6[3], self._vel6[5]
            speed = math.hypot(vx, vz)
            fx, fz = -self.physics.edge_drag * speed * vx, -self.physics.edge_drag * speed * vz
            edge, com = self.data.site_xpos[self._site_ids[0]], self.data.xipos[self._bucket]
            torque_y = (edge[2] - com[2]) * fx - (edge[0] - com[0]) * fz
            self.data.xfrc_applied[self._bucket] += (fx, 0.0, fz, 0.0, torque_y, 0.0)

    def _update_payload(self) -> None:
        """The env writes the dig model's load into the ``payload`` body; scale its mass and shift its centre."""
        super()._update_payload()
        p = self.physics
        if p.payload_mass_factor == 1.0 and p.payload_com_offset == (0.0, 0.0):
            return
        m, b = self.model, self._payload_body
        if self._written is not None and m.body_mass[b] == self._written[0] and np.array_equal(
                m.body_ipos[b], self._written[1]):
            return  # unchanged since we last wrote it
        m.body_mass[b] *= p.payload_mass_factor
        m.body_inertia[b] *= p.payload_mass_factor
        m.body_ipos[b, [0, 2]] += p.payload_com_offset
        qpos = self.data.qpos.copy()  # mj_setConst leaves qpos at qpos0
        mujoco.mj_setConst(m, self.data)
        self.data.qpos[:] = qpos
        self._written = (float(m.body_mass[b]), m.body_ipos[b].copy())


def _joint_id(model: mujoco.MjModel, name: str) -> int:
    jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
    if jid < 0:
        names = [model.joint(j).name for j in range(model.njnt)]
        raise ValueError(f"the twin has no joint {name!r}; joints: {names}")
    return jid


def _play_joints(model: mujoco.MjModel, pin: str) -> list[int]:
    return [j for j in range(model.njnt) if model.joint(j).name.startswith(f"{pin}_play")]


def _add_play(spec: mujoco.MjSpec, pin: str, loader: Any, options: Any) -> None:
    """Clearance joints at a pin: two slides of the bucket at O, or one slide along link B for pin 21."""
    g = loader.geometry
    if pin == "pin_O":
        body, axes = spec.body("bucket"), {"x": [1.0, 0.0, 0.0], "z": [0.0, 0.0, 1.0]}
    else:
        tip = np.asarray(g.pin_21) - np.asarray(g.bell_crank_bottom)
        tip = tip / np.linalg.norm(tip)
        body, axes = spec.body("link_b"), {"axis": [float(tip[0]), 0.0, float(tip[1])]}
    for tag, axis in axes.items():
        body.add_joint(type=mujoco.mjtJoint.mjJNT_SLIDE, name=f"{pin}_play_{tag}", axis=axis, range=[-1e-9, 1e-9],
                       limited=mujoco.mjtLimited.mjLIMITED_TRUE, solref_limit=[options.constraint_timeconst, 1.0],
                       solimp_limit=options.solimp, armature=1e-3 * loader.masses.bucket)


def _make_compliant(spec: mujoco.MjSpec, cylinder: str, loader: Any) -> None:
    """The cylinder's servo integrates the valve flow into a reference stroke that drives the rod through a spring
    (the oil column): force = k (reference − stroke). The stiffness is set at run time from the compliance."""
    act = spec.actuator(cylinder)
    cyl = getattr(loader, cylinder)
    lo, hi = -cyl.max_retract_force, cyl.max_extend_force
    ctrl = list(act.ctrlrange)
    act.set_to_intvelocity(kp=1.0, kv=0.0)
    act.ctrlrange = ctrl
    act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
    act.forcerange = [lo, hi]
    act.actlimited = mujoco.mjtLimited.mjLIMITED_FALSE


def nominal_params(overrides: Mapping[str, Any] | None = None) -> PhysicsParams:
    """:class:`PhysicsParams` with ``overrides`` applied."""
    return dataclasses.replace(PhysicsParams(), **dict(overrides or {}))
