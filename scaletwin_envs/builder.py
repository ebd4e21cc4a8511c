"""One procedural builder: a :class:`LoaderSpec` in, a MuJoCo model of that loader (at any size) out.

The model is assembled in the reference pose (boom lowered, bucket floor on the ground) where every joint
is at zero and every loop closure is satisfied. Lengths, masses, stiffness and time constants all follow the
spec, so the same code builds an 11 kg RC miniature and an 80 t loader. The timestep is the Froude step (1 ms × √λ)
divided into as many equal parts as the tilt cylinder's velocity servo needs (:func:`timestep_substeps`).

Names other modules rely on: bodies ``frame``, ``boom``, ``bucket``, ``payload``, ``bell_crank``, ``link_b``,
``lift_barrel``, ``lift_rod``, ``tilt_barrel``, ``tilt_rod``; joints ``drive``, ``boom_hinge``,
``bucket_hinge``, ``bell_crank_hinge``, ``link_b_hinge``, ``lift_barrel_hinge``, ``tilt_barrel_hinge`` and the
cylinder slides ``lift_cylinder``, ``tilt_cylinder``; sites ``pin_O``, ``pin_21`` and one per pin; equality
constraints ``link_b_to_bucket``, ``lift_rod_to_boom``, ``tilt_rod_to_bell_crank``; with the constraint servo
(default) the supply bodies and slides ``lift_supply``, ``tilt_supply`` and the relief tendons ``lift_relief``,
``tilt_relief`` (:func:`tune_relief` must follow every compile).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from scaletwin_envs.physics.kinematics import bucket_stops
from scaletwin_envs.physics.mass_layout import ROD_FRACTION, BodyLayout, chassis_com, cylinder_axis, linkage_layout
from scaletwin_envs.specs.loader import GRAVITY, CylinderSpec, LoaderSpec

HINGE_AXIS = (0.0, -1.0, 0.0)  # positive angles turn x towards z: boom up, bucket curled back
BASE_TIMESTEP = 1e-3  # s: the Froude step at the ER12 (λ = 1), scaled by √λ; the constraint time constants follow it
SERVO_DROOP = 0.01  # a cylinder at relief force slips at this fraction of its rated speed (velocity servo gain)
# Reflected inertia on each cylinder's slide, as a fraction of boom + bucket + rated load (kg): stands for the oil
# column and keeps MuJoCo's constraint solver well conditioned when a stiff velocity servo drives a light rod
# inside a closed loop (with a light rod the loaded linkage jitters). Scales with mass, so similarity is kept;
# the Newton–Euler route accounts for it as an axial inertial force.
CYLINDER_ARMATURE = 1.0
# Pressure override of the relief valve and flow losses, as viscous damping on each cylinder slide: 10 % of the
# relief force at rated speed (estimate). Physically a relief valve's pressure rises with the flow it passes. With the
# legacy actuator servo it also keeps implicit damping on the slide while the servo is saturated at relief (stall),
# which MuJoCo otherwise drops, and without which a stalled bucket chatters; the constraint servo needs no such help
# (it is 1/1000 of the servo gain: far too little to stop the relay, see SERVO_KINDS), so it stays as physics only.
CYLINDER_DAMPING = 0.1
STOP_WIDTH = 1e-3  # rad: solimp transition width of the bucket stops (an angle: the same at every size)
PILE_COLUMNS = 48  # visual boxes drawing the pile surface
# How each cylinder's velocity servo and relief valve are modelled (BuildOptions.servo):
# "constraint" (default): the valve is a velocity source (a "supply" slide, run at the commanded speed) and the
# servo a friction-loss constraint on the relief tendon (slide − supply), bounded by the relief forces, softened so
# that unclamped it is exactly the velocity servo of gain servo_gain (tune_relief). MuJoCo's constraint solver
# decides whether the relief is open with the end-of-step speeds, the force is bounded inside the solve, and the
# servo is integrated implicitly whether or not it is at relief: no relay, at any timestep. The scripted dig
# converges at the Froude step at all 26 machines of benchmarks/env_throughput.py --servo-sweep: halving it moves
# F21 by 0.01-0.15 % (the mini: 0.03 % at 54 servo time constants per step), with the soil force read at the state
# it acts on (envs.loader_base; before that fix two of the 26 were 1.2-1.3 % off). Against the legacy servo at its
# rule's steps F21 over the scripted dig moved by 0.06 % (ER12), 0.47 % (WA475), 0.58 % (mini).
# "actuator" (legacy, kept for the discrepancy twin, whose structure variants edit that actuator): a force-limited
# velocity actuator on the slide. While it is clamped at relief MuJoCo integrates its force explicitly (it drops
# the servo's implicit damping), and one step changes the slide's speed by up to dt / τ times the speed band in
# which the servo is unclamped; the servo can then lock into a relay between its extend and retract limits,
# switching every physics step, which moves the dig's pin forces (mini at its Froude step: F21 62 % off).
SERVO_KINDS = ("constraint", "actuator")
# Legacy servo only: most physics steps per tilt-servo time constant τ (slide inertia over servo gain,
# servo_time_constant). 21 is the ER12's own ratio (20.9) at its Froude step, where its dig is converged; it bounds
# the relay but is no guarantee (16 of 26 sampled machines converged at this rule's steps; benchmarks/results/
# env_throughput.md, "before" columns).
MAX_STEPS_PER_SERVO_TAU = 21.0
# The supply slide stands for the pump and valve: an ideal flow source, which the cylinder's own load cannot slow.
# MuJoCo's constraint solver predicts every slide's motion from its inertia alone (the implicit damping of an
# actuator enters only after the solve), so the supply must be heavy to be read as a velocity source there: at
# 10^4 times the slide's inertia the relief force moves it by 10^-4 of what it moves the slide (10^3 or 10^5 move
# F21 over the dig by < 0.002 %, 10^6 by 0.015 %: conditioning). Not in the linkage (its own body, coupled only
# through the relief tendon), so the linkage's mass, loads and pin forces are untouched.
SUPPLY_INERTIA = 1e4
# The supply's own velocity servo (the actuator the env's ctrl drives, unlimited): time constant 10^-3 timesteps,
# so that (implicitly integrated) it holds the commanded speed to 0.1 % of any drift per step; the env also sets
# the supply's speed whenever it sets ctrl, so the solver never sees it accelerate (10^-2 or 10^-4 timesteps move F21
# over the dig by < 10^-4 %).
SUPPLY_TIME = 1e-3
# Bounds on a timestep passed explicitly, as fractions of the Froude step: at most 2, where the constraint time
# constant (4 Froude steps) reaches MuJoCo's floor of 2 timesteps (beyond it MuJoCo softens every loop and contact
# silently); at least 1/1000, where one scripted dig already costs minutes of CPU (a smaller value is a unit error).
TIMESTEP_RANGE = (1e-3, 2.0)


def froude_timestep(spec: LoaderSpec) -> float:
    """The Froude step, s: 1 ms × √λ (the control step and the soil refresh period are counted in it)."""
    return BASE_TIMESTEP * math.sqrt(spec.scale)


def servo_gain(cylinder: CylinderSpec) -> float:
    """Gain of a cylinder's velocity servo, N·s/m: relief force over the slip speed :data:`SERVO_DROOP` allows."""
    return cylinder.max_extend_force / (SERVO_DROOP * cylinder.extend_speed)


def servo_time_constant(spec: LoaderSpec, which: str = "tilt", armature_factor: float = 1.0) -> float:
    """Time constant of a cylinder's velocity servo, s: the inertia on its slide (armature, times
    ``armature_factor`` where an env enlarges it, plus the rod) over the servo gain."""
    cyl = spec.lift if which == "lift" else spec.tilt
    return (armature_factor * cylinder_armature(spec) + cyl.rod_mass) / servo_gain(cyl)


def timestep_substeps(spec: LoaderSpec, tilt_armature_factor: float = 1.0, servo: str = "constraint") -> int:
    """Parts the Froude step is divided into: 1 with the constraint servo (it is integrated implicitly at relief
    too); with the legacy actuator servo the fewest that keep the timestep within :data:`MAX_STEPS_PER_SERVO_TAU`
    tilt-servo time constants (1 for the ER12 and the WA475, 3 for the mini)."""
    if servo not in SERVO_KINDS:
        raise ValueError(f"servo must be one of {SERVO_KINDS}, got {servo!r}")
    if servo == "constraint":
        return 1
    ratio = froude_timestep(spec) / servo_time_constant(spec, "tilt", tilt_armature_factor)
    return max(1, math.ceil(ratio / MAX_STEPS_PER_SERVO_TAU - 1e-9))


def check_timestep(spec: LoaderSpec, timestep: float) -> float:
    """``timestep`` (s) as a float if it is a finite number within :data:`TIMESTEP_RANGE` Froude steps; else
    ``ValueError``."""
    froude = froude_timestep(spec)
    lo, hi = (f * froude for f in TIMESTEP_RANGE)
    ok = isinstance(timestep, int | float) and not isinstance(timestep, bool) and math.isfinite(timestep)
    if not (ok and lo <= timestep <= hi):
        raise ValueError(f"timestep must be a number of seconds in [{lo:.3g}, {hi:.3g}] for {spec.name!r} "
                         f"({TIMESTEP_RANGE[0]:g} to {TIMESTEP_RANGE[1]:g} times its Froude step of {froude:.3g} s), "
                         f"got {timestep!r}")
    return float(timestep)


@dataclass(frozen=True)
class BuildOptions:
    """Numerical settings derived from the spec (all scale with √λ or λ)."""

    timestep: float
    constraint_timeconst: float
    constraint_width: float  # m: solimp transition width, scaled with the machine so similarity holds
    servo: str = "constraint"  # one of SERVO_KINDS

    @classmethod
    def for_spec(cls, spec: LoaderSpec, timestep: float | None = None, tilt_armature_factor: float = 1.0,
                 servo: str = "constraint") -> BuildOptions:
        """The options of ``spec``: ``timestep`` (s; None: the Froude step over :func:`timestep_substeps`, with the
        tilt slide's armature × ``tilt_armature_factor`` as built, for ``servo``, one of :data:`SERVO_KINDS`) and
        constraint time constants of 4 Froude steps whatever the timestep (the loops' and contacts' softness is
        physics, the same at every timestep)."""
        froude = froude_timestep(spec)
        if timestep is None:
            dt = froude / timestep_substeps(spec, tilt_armature_factor, servo)
        else:
            timestep_substeps(spec, tilt_armature_factor, servo)  # checks servo
            dt = check_timestep(spec, timestep)
        return cls(timestep=dt, constraint_timeconst=4.0 * froude,
                   constraint_width=1e-3 * spec.characteristic_length, servo=servo)

    @property
    def solimp(self) -> list[float]:
        return [0.9, 0.95, self.constraint_width, 0.5, 2.0]


def xz_to_xyz(p: np.ndarray | tuple[float, float], y: float = 0.0) -> list[float]:
    """A planar (x, z) point as a MuJoCo 3-vector at lateral offset y (m)."""
    return [float(p[0]), y, float(p[1])]


def _inertial(body: mujoco.MjsBody, mass: float, com: np.ndarray, inertia: float) -> None:
    body.explicitinertial = True
    body.mass = mass
    body.ipos = xz_to_xyz(com)
    body.inertia = [inertia, inertia, inertia]


def _capsule(body: mujoco.MjsBody, a: np.ndarray, b: np.ndarray, radius: float, rgba: tuple[float, ...],
             y: float = 0.0) -> None:
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=xz_to_xyz(a, y) + xz_to_xyz(b, y), size=[radius, 0, 0],
                  contype=0, conaffinity=0, rgba=list(rgba))


def _hinged_body(parent: mujoco.MjsBody, name: str, joint: str, pos: np.ndarray, layout: BodyLayout
                 ) -> mujoco.MjsBody:
    """A child body at ``pos`` (m, in the parent's frame) turning about the y axis, with its layout's inertia."""
    body = parent.add_body(name=name, pos=xz_to_xyz(pos))
    body.add_joint(type=mujoco.mjtJoint.mjJNT_HINGE, name=joint, axis=list(HINGE_AXIS))
    _inertial(body, layout.mass, layout.com, layout.inertia)
    return body


def build_spec(spec: LoaderSpec, options: BuildOptions | None = None) -> mujoco.MjSpec:
    """The :class:`mujoco.MjSpec` of a loader (not compiled, so callers may edit it first)."""
    opt = options or BuildOptions.for_spec(spec)
    g, lay, s = spec.geometry, linkage_layout(spec), mujoco.MjSpec()
    L = spec.characteristic_length
    s.modelname = f"wheel_loader_{spec.name}".replace(" ", "_")
    s.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    s.compiler.degree = False  # joint ranges in rad
    s.option.timestep = opt.timestep
    s.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    s.option.gravity = [0.0, 0.0, -GRAVITY]
    s.visual.global_.offwidth, s.visual.global_.offheight = 640, 480
    s.stat.extent = 3.0 * L
    s.stat.center = [L, 0.0, 0.5 * L]
    _world(s, spec, opt)
    frame = s.worldbody.add_body(name="frame")
    frame.add_joint(type=mujoco.mjtJoint.mjJNT_SLIDE, name="drive", axis=[1.0, 0.0, 0.0])
    _inertial(frame, spec.masses.chassis, chassis_com(spec), spec.masses.chassis * L * L / 6.0)
    _chassis_visual(frame, spec)
    piv = np.asarray(g.boom_pivot)
    for name in ("boom_pivot", "lift_frame_pin", "tilt_frame_pin"):
        frame.add_site(name=name, pos=xz_to_xyz(getattr(g, name)), size=[0.02 * L, 0, 0])
    boom = _add_boom(frame, spec, lay, piv)
    _add_bucket(boom, spec, lay, piv, opt)
    _add_bell_crank(boom, spec, lay, piv)
    for which in ("lift", "tilt"):
        _add_cylinder(frame, spec, lay, which)
    _equalities(s, opt)
    _actuators(s, spec, opt)
    _soil_dampers(s, spec)
    return s


def _soil_dampers(s: mujoco.MjSpec, spec: LoaderSpec) -> None:
    """Two spatial tendons from the cutting edge to anchors far ahead and far above: with a damping coefficient
    set at run time they resist the edge's velocity isotropically, integrated implicitly by MuJoCo (the soil's
    Coulomb-like resistance as a velocity-dependent damper, free of the chatter an explicit force would cause)."""
    far = 1e3 * spec.characteristic_length
    for name, pos in (("soil_anchor_x", [far, 0.0, 0.0]), ("soil_anchor_z", [0.0, 0.0, far])):
        s.worldbody.add_site(name=name, pos=pos, size=[0.01, 0, 0])
        tendon = s.add_tendon(name=name.replace("anchor", "damper"), group=3)  # group 3: not drawn by default
        tendon.wrap_site("bucket_edge")
        tendon.wrap_site(name)


def build_model(spec: LoaderSpec, options: BuildOptions | None = None) -> mujoco.MjModel:
    """Compile the loader model."""
    model = build_spec(spec, options).compile()
    tune_relief(model, spec)
    return model


def supply_dofs(model: mujoco.MjModel, spec: LoaderSpec) -> list[tuple[int, float]]:
    """(dof address, speed offset m/s) of the lift and the tilt supply slides (empty with the legacy actuator servo):
    a supply runs at the commanded slide speed minus its offset (the relief centre over the servo gain)."""
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "lift_supply") < 0:
        return []
    return [(int(model.joint(f"{w}_supply").dofadr[0]), relief_offset(c)[1] / servo_gain(c))
            for w, c in (("lift", spec.lift), ("tilt", spec.tilt))]


def tune_relief(model: mujoco.MjModel, spec: LoaderSpec) -> None:
    """Make each relief tendon's friction loss the velocity servo of gain :func:`servo_gain` (a no-op with the
    legacy actuator servo). MuJoCo solves a friction-loss row for the force f in [−F, F] that minimises
    ½ M-weighted change of motion + ½ R f², with f = −(a − a_ref) / R inside the bounds, a the row's (slide −
    supply) acceleration. With a_ref = −v / dt (damping 1 / dt, no stiffness: solref = [0, −d / dt], MuJoCo
    divides by d) and R = 1 / (kv dt), a − a_ref = v_end / dt and f = −kv v_end: the servo's force on the
    end-of-step speed error, i.e. the velocity servo integrated implicitly, as MuJoCo integrates the unclamped
    actuator; at the bounds f = ±F (the relief valve) and the solver keeps it there only while the end-of-step
    speed error still asks for more. MuJoCo sets R = (1 − d) / d × the row's diagonal approximation (the tendon's
    invweight0), hence the impedance d = x / (1 + x) with x = kv dt invweight0 (dmin = dmax = d: no dependence on
    position). Call after every compile and after changing the timestep or the slides' inertia."""
    dt = float(model.opt.timestep)
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TENDON, "lift_relief") < 0:
        return
    for which, cyl in (("lift", spec.lift), ("tilt", spec.tilt)):
        t = model.tendon(f"{which}_relief").id
        x = servo_gain(cyl) * dt * float(model.tendon_invweight0[t])
        d = min(max(x / (1.0 + x), 1e-4), 0.9999)
        model.tendon_solimp_fri[t] = [d, d, 1e-3, 0.5, 2.0]
        model.tendon_solref_fri[t] = [0.0, -d / dt]


def _world(s: mujoco.MjSpec, spec: LoaderSpec, opt: BuildOptions) -> None:
    L = spec.characteristic_length
    w = s.worldbody
    w.add_light(pos=[L, -2 * L, 4 * L], dir=[0, 0.5, -1])
    s.visual.headlight.ambient = [0.35, 0.35, 0.35]
    w.add_geom(name="ground", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[20 * L, 4 * L, 0.1 * L],
               rgba=[0.55, 0.52, 0.45, 1], condim=1,  # frictionless: the bucket skims the floor; soil drag is modelled
               solref=[opt.constraint_timeconst, 1.0], solimp=opt.solimp)
    for k in range(PILE_COLUMNS):
        w.add_geom(name=f"pile_{k}", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.05 * L, 0.4 * L, 1e-3 * L],
                   pos=[0, 0, -L], contype=0, conaffinity=0, rgba=[0.62, 0.5, 0.33, 1])
    w.add_camera(name="side", pos=[1.5 * L, -4.6 * L, 1.0 * L], xyaxes=[1, 0, 0, 0, 0, 1],
                 mode=mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM)


def _chassis_visual(frame: mujoco.MjsBody, spec: LoaderSpec) -> None:
    L = spec.characteristic_length
    frame.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, pos=[-0.75 * L, 0, 0.45 * L], size=[0.6 * L, 0.3 * L, 0.18 * L],
                   contype=0, conaffinity=0, rgba=[0.9, 0.7, 0.1, 1])
    for x in (-1.1 * L, -0.25 * L):
        frame.add_geom(type=mujoco.mjtGeom.mjGEOM_CYLINDER, pos=[x, -0.35 * L, 0.25 * L], size=[0.25 * L, 0.06 * L, 0],
                       quat=[math.cos(math.pi / 4), math.sin(math.pi / 4), 0, 0], contype=0, conaffinity=0,
                       rgba=[0.1, 0.1, 0.1, 1])


def _add_boom(frame: mujoco.MjsBody, spec: LoaderSpec, lay: dict, piv: np.ndarray) -> mujoco.MjsBody:
    g, L = spec.geometry, spec.characteristic_length
    boom = _hinged_body(frame, "boom", "boom_hinge", piv, lay["boom"])
    o, c, lb = (np.asarray(v) - piv for v in (g.pin_O, g.bell_crank_pivot, g.lift_boom_pin))
    _capsule(boom, np.zeros(2), o, 0.035 * L, (0.9, 0.7, 0.1, 1))
    _capsule(boom, c, 0.5 * o, 0.025 * L, (0.9, 0.7, 0.1, 1))
    _capsule(boom, lb, 0.45 * o, 0.025 * L, (0.9, 0.7, 0.1, 1))
    for name, p in (("bell_crank_pivot", c), ("lift_boom_pin", lb)):
        boom.add_site(name=name, pos=xz_to_xyz(p), size=[0.02 * L, 0, 0])
    return boom


def _add_bucket(boom: mujoco.MjsBody, spec: LoaderSpec, lay: dict, piv: np.ndarray, opt: BuildOptions) -> None:
    g, L = spec.geometry, spec.characteristic_length
    o = np.asarray(g.pin_O)
    b = lay["bucket"]
    bucket = _hinged_body(boom, "bucket", "bucket_hinge", o - piv, b)
    # The bucket's rack-back and dump stops on the boom: short of link B's dead centres by BUCKET_STOP_MARGIN
    # (physics.kinematics.bucket_stops), with the loops' stiffness and a 1 mrad transition (an angle: the same at
    # every size).
    hinge = bucket.joints[0]
    hinge.range = list(bucket_stops(g))  # rad: build_spec sets compiler.degree = False
    hinge.limited = mujoco.mjtLimited.mjLIMITED_TRUE
    hinge.solref_limit = [opt.constraint_timeconst, 1.0]
    hinge.solimp_limit = [0.9, 0.95, STOP_WIDTH, 0.5, 2.0]
    heel, edge, top = (np.asarray(v) - o for v in (g.bucket_heel, g.bucket_edge, g.bucket_back_top))
    half_w, t = 0.5 * g.bucket_width, 0.02 * L
    inward = (edge - heel) + (top - heel)  # plates lie inside the outline so the outline is the contact surface
    for a, z in ((heel, edge), (heel, top)):
        vec = z - a
        normal = np.array([-vec[1], vec[0]]) / float(np.hypot(*vec))
        mid = 0.5 * (a + z) + t * (normal if np.dot(normal, inward) > 0 else -normal)
        angle = math.atan2(vec[1], vec[0])
        size = [0.5 * float(np.hypot(*vec)), half_w, t]
        bucket.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, pos=xz_to_xyz(mid), size=size,
                        quat=[math.cos(-angle / 2), 0, math.sin(-angle / 2), 0], rgba=[0.35, 0.35, 0.38, 1],
                        condim=1, solref=[opt.constraint_timeconst, 1.0], solimp=opt.solimp)
    for y in (-half_w, half_w):
        _capsule(bucket, edge, top, 0.5 * t, (0.35, 0.35, 0.38, 1), y)
    for name, p in (("pin_O", np.zeros(2)), ("pin_21", np.asarray(g.pin_21) - o), ("bucket_edge", edge),
                    ("bucket_heel", heel), ("bucket_back_top", top)):
        bucket.add_site(name=name, pos=xz_to_xyz(p), size=[0.02 * L, 0, 0])
    payload = bucket.add_body(name="payload")
    _inertial(payload, 1e-9 * b.mass, b.com, 1e-9 * b.inertia)


def _add_bell_crank(boom: mujoco.MjsBody, spec: LoaderSpec, lay: dict, piv: np.ndarray) -> None:
    g, L = spec.geometry, spec.characteristic_length
    c = np.asarray(g.bell_crank_pivot)
    crank = _hinged_body(boom, "bell_crank", "bell_crank_hinge", c - piv, lay["bell_crank"])
    top, bottom = np.asarray(g.bell_crank_top) - c, np.asarray(g.bell_crank_bottom) - c
    _capsule(crank, top, bottom, 0.02 * L, (0.2, 0.2, 0.2, 1), 0.05 * L)
    crank.add_site(name="bell_crank_top", pos=xz_to_xyz(top), size=[0.02 * L, 0, 0])
    crank.add_site(name="bell_crank_bottom", pos=xz_to_xyz(bottom), size=[0.02 * L, 0, 0])
    link = _hinged_body(crank, "link_b", "link_b_hinge", bottom, lay["link_b"])
    tip = np.asarray(g.pin_21) - np.asarray(g.bell_crank_bottom)
    _capsule(link, np.zeros(2), tip, 0.015 * L, (0.2, 0.2, 0.2, 1), 0.05 * L)
    link.add_site(name="link_b_tip", pos=xz_to_xyz(tip), size=[0.015 * L, 0, 0])


def _add_cylinder(frame: mujoco.MjsBody, spec: LoaderSpec, lay: dict, which: str) -> None:
    g, L = spec.geometry, spec.characteristic_length
    cyl = spec.lift if which == "lift" else spec.tilt
    start = np.asarray(g.lift_frame_pin if which == "lift" else g.tilt_frame_pin)
    axis, ref_len = cylinder_axis(spec, which)
    y = -0.12 * L if which == "lift" else 0.12 * L
    barrel = _hinged_body(frame, f"{which}_barrel", f"{which}_barrel_hinge", start, lay[f"{which}_barrel"])
    _capsule(barrel, np.zeros(2), axis * 0.95 * cyl.closed_length, 0.5 * cyl.bore * 1.3, (0.15, 0.15, 0.15, 1), y)
    rod = barrel.add_body(name=f"{which}_rod")
    rod.add_joint(type=mujoco.mjtJoint.mjJNT_SLIDE, name=f"{which}_cylinder", axis=xz_to_xyz(axis),
                  range=[cyl.closed_length - ref_len, cyl.closed_length + cyl.stroke - ref_len],
                  armature=cylinder_armature(spec),
                  damping=[CYLINDER_DAMPING * cyl.max_extend_force / cyl.extend_speed, 0, 0])
    b = lay[f"{which}_rod"]
    _inertial(rod, b.mass, b.com, b.inertia)
    _capsule(rod, axis * (ref_len - ROD_FRACTION * cyl.closed_length), axis * ref_len, 0.5 * cyl.rod_diameter,
             (0.8, 0.8, 0.85, 1), y)
    rod.add_site(name=f"{which}_rod_tip", pos=xz_to_xyz(axis * ref_len), size=[0.015 * L, 0, 0])


def cylinder_armature(spec: LoaderSpec) -> float:
    """Armature of each cylinder slide, kg."""
    return CYLINDER_ARMATURE * (spec.masses.boom + spec.masses.bucket + spec.rated_load)


def _equalities(s: mujoco.MjSpec, opt: BuildOptions) -> None:
    loops = (("link_b_to_bucket", "pin_21", "link_b_tip"), ("lift_rod_to_boom", "lift_boom_pin", "lift_rod_tip"),
             ("tilt_rod_to_bell_crank", "bell_crank_top", "tilt_rod_tip"))
    for name, a, b in loops:
        s.add_equality(name=name, type=mujoco.mjtEq.mjEQ_CONNECT, objtype=mujoco.mjtObj.mjOBJ_SITE,
                       name1=a, name2=b, solref=[opt.constraint_timeconst, 1.0], solimp=opt.solimp)


def relief_offset(cylinder: CylinderSpec) -> tuple[float, float]:
    """(half-width, centre) of a cylinder's force range from its retract to its extend relief force, N: the relief
    tendon's friction loss bounds its force symmetrically (± half-width); a constant force (the centre) on the slide
    shifts that range to [−max_retract_force, max_extend_force]."""
    half = 0.5 * (cylinder.max_extend_force + cylinder.max_retract_force)
    return half, 0.5 * (cylinder.max_extend_force - cylinder.max_retract_force)


def _actuators(s: mujoco.MjSpec, spec: LoaderSpec, opt: BuildOptions) -> None:
    """Actuators ``lift``, ``tilt`` (ctrl: commanded slide speed, m/s) and ``drive`` (ctrl: travel speed, m/s), in
    that order (the env writes ctrl[:3]); with the constraint servo also ``lift_relief_centre`` and
    ``tilt_relief_centre`` (constant forces, no ctrl), the bodies and slides ``lift_supply``, ``tilt_supply`` and
    the fixed tendons ``lift_relief``, ``tilt_relief`` (slide − supply)."""
    for which, cyl in (("lift", spec.lift), ("tilt", spec.tilt)):
        if opt.servo == "actuator":
            act = s.add_actuator(name=which, target=f"{which}_cylinder", trntype=mujoco.mjtTrn.mjTRN_JOINT)
            act.set_to_velocity(kv=servo_gain(cyl))
            act.ctrlrange = [-cyl.retract_speed, cyl.extend_speed]
            act.forcelimited = True
            act.forcerange = [-cyl.max_retract_force, cyl.max_extend_force]
            continue
        # The valve as a velocity source: a heavy slide outside the linkage (SUPPLY_INERTIA) held at the commanded
        # speed by its own stiff servo (SUPPLY_TIME), less the speed the relief centre's force would add through
        # the servo gain (so that the slide's servo sees exactly the commanded speed).
        kv = servo_gain(cyl)
        half, centre = relief_offset(cyl)
        slide = cylinder_armature(spec) + cyl.rod_mass
        inertia = SUPPLY_INERTIA * slide
        supply = s.worldbody.add_body(name=f"{which}_supply")
        supply.add_joint(type=mujoco.mjtJoint.mjJNT_SLIDE, name=f"{which}_supply", axis=[1.0, 0.0, 0.0],
                         armature=inertia)
        _inertial(supply, 1e-9 * slide, np.zeros(2), 1e-9 * slide)  # its inertia is its armature (mass: ~none)
        act = s.add_actuator(name=which, target=f"{which}_supply", trntype=mujoco.mjtTrn.mjTRN_JOINT)
        gain = inertia / (SUPPLY_TIME * opt.timestep)
        act.set_to_velocity(kv=gain)
        act.biasprm[0] = -gain * centre / kv
        act.ctrlrange = [-cyl.retract_speed, cyl.extend_speed]
        # The servo and relief valve: friction loss on slide − supply, bounded by ± half the relief range (its
        # softness set after compiling, tune_relief); the relief centre is a constant force on the slide.
        relief = s.add_tendon(name=f"{which}_relief", group=3)  # group 3: not drawn by default
        relief.wrap_joint(f"{which}_cylinder", 1.0)
        relief.wrap_joint(f"{which}_supply", -1.0)
        relief.frictionloss = half
    # Drive: a torque-converter characteristic, force = traction × (command − v / v_max): full rimpull at stall,
    # none at top speed. As a pure velocity servo it also keeps MuJoCo's implicit damping on the frame.
    traction = spec.traction_coefficient * spec.weight
    act = s.add_actuator(name="drive", target="drive", trntype=mujoco.mjtTrn.mjTRN_JOINT)
    act.set_to_velocity(kv=traction / spec.travel_speed)
    act.ctrlrange = [-spec.travel_speed, spec.travel_speed]
    act.forcelimited = True
    act.forcerange = [-traction, traction]
    if opt.servo == "constraint":
        for which, cyl in (("lift", spec.lift), ("tilt", spec.tilt)):
            act = s.add_actuator(name=f"{which}_relief_centre", target=f"{which}_cylinder",
                                 trntype=mujoco.mjtTrn.mjTRN_JOINT)
            act.gaintype, act.biastype = mujoco.mjtGain.mjGAIN_FIXED, mujoco.mjtBias.mjBIAS_AFFINE
            act.gainprm[0] = 0.0
            act.biasprm[:3] = [relief_offset(cyl)[1], 0.0, 0.0]
