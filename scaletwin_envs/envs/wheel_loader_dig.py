"""WheelLoaderDig-v1: a wheel loader of any size fills its bucket from a soil pile.

The machine (:mod:`scaletwin_envs.builder`) drives straight at a pile (:mod:`scaletwin_envs.physics.pile`)
whose resistance follows the fundamental earthmoving equation (:mod:`scaletwin_envs.physics.dig`); material
inside the bucket cavity becomes part of the combined bucket + load body, whose mass and centre of mass
change as it fills and spills. Every step logs the paper's Eq. (10) and Eq. (23) signals in
``info["signals"]`` (SI); each pin force also by a second, independent route (``two_route_check``): every
step with ``True``, and by default while a recorder watches the env.

Action: ``[lift, tilt, drive]`` in [-1, 1]; positive raises the boom, curls the bucket back, drives forward;
0 holds. Observation: dimensionless (lengths / boom length L, speeds / √(gL), forces / weight or relief
force, time / max episode time), so one policy acts at every scale; names in :data:`OBS_NAMES`.
Reward: fill gained (fraction of heaped capacity) minus time, hydraulic energy and spill costs; each term in
``info["reward_terms"]``. The episode terminates when the loaded bucket has been lifted clear of the pile and
the machine has pulled back (``info["success"]`` if the fill factor reaches ``success_fill``), and is truncated
at ``max_episode_time`` (Froude time units) or on a physics blow-up (``info["sim_error"]``).

Registration: ``max_episode_steps`` is :data:`scaletwin_envs.MAX_EPISODE_STEPS` (290), the control steps in the
default ``max_episode_time`` at the default ``frame_skip`` at every scale and timestep (the control step, 100 Froude
steps of 1 ms × √λ, and the Froude time both grow as √λ); when changing either, pass
``max_episode_steps=horizon_steps(max_episode_time, frame_skip, ...)`` to ``gym.make`` as well, or gymnasium's
``TimeLimit`` truncates at 290 steps (``env.unwrapped.horizon`` is the env's own).

Timestep: by default the Froude step (1 ms × √λ; :func:`scaletwin_envs.builder.timestep_substeps` is 1 with the
cylinders' constraint servo, :data:`scaletwin_envs.builder.SERVO_KINDS`); ``timestep=`` (s) sets another, e.g.
for a convergence check. ``frame_skip`` and ``external_force_substeps`` count
physics steps at the env's timestep; left None they keep the control step at 100 Froude steps and the soil refresh
at 20 (then the timestep must divide those periods).

Info: every step returns the same keys (:data:`INFO_KEYS`), a ``sim_error`` step included: ``sim_error`` is None,
or why the physics failed; then the signals are those of the last good step, the reward terms 0.0, the phase
``"error"``, and stepping again without ``reset`` raises
:class:`~scaletwin_envs.envs.loader_base.EpisodeFinishedError`. ``action_clipped`` says whether the action had a
component outside [-1, 1]: such actions are clipped to it, as gymnasium's MuJoCo v5 environments do.

Reset options (``reset(seed=..., options={...})``, see :data:`WheelLoaderDigEnv.RESET_OPTIONS`): a value given
is used exactly, for this episode only, instead of the nominal value plus its random perturbation; the random
draws are made all the same, so the quantities not given are those the same seed gives without options. Any
other key, or a value out of range, raises ``ValueError``.

Version history:
    v0: initial release (scaletwin 0.1).
    v0 (2026-11-25, same dynamics and signals): registered with ``max_episode_steps=290``; the same info keys on
    a ``sim_error`` step and an error on stepping after it; ``info["action_clipped"]``; ``reset(options=...)``
    honoured (start pose, pile); ``law`` other than the default with a preset or LoaderSpec raises ``ValueError``
    (it was ignored); ``render_mode="human"`` without a display raises ``ValueError`` (the GL library aborted);
    the per-step soil force, signals and observation code reads MuJoCo's arrays with less Python overhead, with
    bit-identical results. No value a step returns changed, so the id stays v0.
    v0 (2026-11-26, same dynamics, observations and rewards, bit for bit): ``two_route_check`` defaults to
    ``None``: the second route to the pin forces (``*_route2``, ``residual_*`` signals) is computed while a
    recorder watches the env (``EpisodeRecorder``/``RerunLogger``: recordings, sweeps, replays, ``scaletwin
    simulate --parquet/--rrd``) or every step with ``two_route_check=True``; a plain ``gym.make`` no longer
    solves it on every step (a quarter of the env's own time per step), and its signals lack those keys, as
    with ``two_route_check=False`` before. The per-step signals, soil force, fill transfer and observation run
    with less Python overhead, every value bit-identical: ``env.step`` from 0.67–0.69 to 0.82–0.83 of raw
    ``mj_step`` (0.58–0.61 to 0.75–0.77 with route 2; ``benchmarks/results/env_throughput.md``, side by side on
    2 shared AVX-512 cores; 0.80–0.83 over five such runs). Signal values
    are plain floats (some were ``np.float64``). The physics timestep stays Froude-scaled (1 ms × √λ): doubling it
    moves the mini's F21 over the dig by 12.5 % (mean absolute), so it is no free numerical choice.
    v0 (2026-11-26, dynamics changed where the timestep did; the ER12 and the WA475 bit for bit as before): the
    physics timestep is the Froude step divided into as many parts as keep it within 21 tilt-servo time constants
    (:func:`scaletwin_envs.builder.timestep_substeps`), since a servo clamped at relief is integrated explicitly and
    at larger ratios locks into a relay between its force limits: the mini's step is 0.126 ms (was 0.378 ms, where
    its dig's F21 was 10 % off its value at the new step; now halving the step moves it by 0.63 %), and most
    product-line machines below λ ≈ 1 (some above) get 2-4 parts. ``frame_skip`` and ``external_force_substeps``
    default to None, the same control step and soil refresh period in seconds as before (300 and 60 physics steps
    at the mini); ``timestep=`` sets the physics step explicitly (a finite number of seconds within 1/1000 to 2
    Froude steps). The control step, horizon, observation and reward definitions are unchanged; the mini's
    observations and rewards differ where the finer step integrates the relief stall differently. The rule is no
    guarantee elsewhere: 16 of 26 machines sampled over the product line converge at it
    (``benchmarks/results/env_throughput.md``). The id stayed v0 although the mini's dynamics changed.
    v1 (2026-11-26; dynamics changed everywhere, slightly, so the id moved on: ``WheelLoaderDig-v0`` is no longer
    registered, and ``gym.make`` of it names v1): each cylinder's velocity servo and relief
    valve is a friction-loss constraint on a relief tendon between the slide and a supply slide (the valve, a
    velocity source at the commanded speed), softened to the same gain and bounded by the same relief forces
    (:data:`scaletwin_envs.builder.SERVO_KINDS`, :func:`scaletwin_envs.builder.tune_relief`): MuJoCo's solver
    bounds the force inside the solve and the servo stays implicit at relief, so it no longer relays. The timestep
    is the Froude step everywhere (the mini's 0.378 ms again); halving it moves F21 over the scripted dig by
    0.01-0.15 % at all 26 sampled machines (with the soil refresh below; 24 of 26 under 1 % without it). Against
    the code before (servo alone): F21 over the scripted dig 0.06 % (ER12), 0.47 % (WA475), 0.58 % (mini, against
    0.126 ms) mean absolute; on carrying holds, where the old servo relayed at relief on 8 % of the
    ER12's control steps, 4-8 %, the new converged (halving the step: 0.2-0.5 % against 6-9 % before). The
    observation's servo forces are the relief tendon's force plus the relief centre, with no relay (the policies
    were trained on the relaying output). Two more slides (``lift_supply``, ``tilt_supply``) and two constant-force
    actuators (``lift_relief_centre``, ``tilt_relief_centre``) in the model: nq, nv and nu grow (ctrl[:3] is as
    before), so saved MuJoCo states of the old model do not load. The soil force refreshed inside a control step
    reads the state it acts on (``mj_step`` leaves the kinematics of its last step's start; the refresh read them one
    physics step late), so the dig no longer depends on the control step: the same commands at a fifth of it moved
    F21 by 0.9 % RMS / 4 % max of its range at the ER12 and 2.2 / 13 % at the WA475, now within 3e-5. Recordings
    and checkpoints made with v0 name it in their provenance; ``WheelLoaderDigRandom`` and ``WheelLoaderLoadTruck``
    moved to v1 with it.
    v1 (2026-11-26, dynamics changed only where the bucket meets its new stop; the id stays v1): the bucket has a
    rack-back stop on the boom (the joint ``bucket_hinge`` is limited), 10° short of the angle at which link B
    and the bucket's lever come in line (:func:`scaletwin_envs.physics.kinematics.bucket_stops`). Without it a
    full rack-back at a raised boom drove the linkage to within 3° of that dead centre (ER12), and on machines of
    the product line a rack-back at relief, or a lowered boom pressing the bucket into the ground, took the Z-bar
    over to its other assembly branch (bucket pitch 0.3–1.9 rad off what the cylinder lengths give on 328 hold
    rows of 3 of the 40 machines drawn with design seed 0). The scripted dig of the presets never reaches the stop
    and records bit for bit as before (as do the paper's and the zoo's recordings); the second route to the pin
    forces counts the stop's moment on the bucket and the boom.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, ClassVar

import mujoco
import numpy as np
from gymnasium import spaces

from scaletwin_envs.builder import BuildOptions, froude_timestep
from scaletwin_envs.envs.loader_base import DEFAULT_FRAME_SKIP, LoaderEnv
from scaletwin_envs.envs.phases import DigPhase, classify
from scaletwin_envs.physics.bucket import centroid_at, centroid_ends, heaped_capacity
from scaletwin_envs.physics.dig import DigForces, DigModel
from scaletwin_envs.physics.kinematics import LinkageUnreachable, solve_pose
from scaletwin_envs.physics.pile import Pile
from scaletwin_envs.runtime import draw_pile, qpos_for_pose, set_payload
from scaletwin_envs.specs import make_loader
from scaletwin_envs.specs.laws import PRODUCT_LINE, ScalingLaw
from scaletwin_envs.specs.loader import GRAVITY, LoaderSpec
from scaletwin_envs.specs.soil import SoilSpec, make_soil

OBS_NAMES = (
    "boom_angle", "bucket_pitch", "lift_extension", "tilt_extension", "lift_speed", "tilt_speed", "travel_speed",
    "edge_x_to_pile", "edge_height", "edge_depth", "surface_ahead_1", "surface_ahead_2", "fill",
    "lift_force", "tilt_force", "soil_force", "time", "spilled", "advance",
)
OBS_INDEX = {n: i for i, n in enumerate(OBS_NAMES)}
OBS_LIMIT = 10.0
#: Keys of every step's ``info`` (a ``sim_error`` step included).
INFO_KEYS = ("signals", "phase", "reward_terms", "fill_factor", "loaded_mass", "spilled_mass", "hydraulic_work",
             "time", "success", "sim_error", "action_clipped")
REWARD_TERMS = ("fill", "time", "energy", "spill")


def horizon_steps(max_episode_time: float = 60.0, frame_skip: int | None = None,
                  loader: LoaderSpec | None = None, timestep: float | None = None) -> int:
    """Control steps after which the env truncates itself, for ``max_episode_time`` (Froude times) and ``frame_skip``.
    With ``frame_skip`` None (the default control step of 100 Froude steps) the same at every scale, law and
    timestep; an explicit ``frame_skip`` counts physics steps of ``timestep`` (s), by default the env's default
    timestep for ``loader`` (default the ER12, whose timestep is its Froude step). Pass it as
    ``gym.make(..., max_episode_steps=horizon_steps(t, ...))`` when changing either from its default."""
    spec = loader if loader is not None else make_loader("er12")
    froude = froude_timestep(spec)
    if frame_skip is None:
        control = DEFAULT_FRAME_SKIP * froude
    else:
        control = frame_skip * (BuildOptions.for_spec(spec, timestep).timestep)
    return math.ceil(max_episode_time * spec.froude_time / control - 1e-9)


def _positive(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return float(value)


class WheelLoaderDigEnv(LoaderEnv):
    """Dig one bucket of soil from a pile (see module docstring).

    Args:
        scale: preset (``"mini"``, ``"er12"``, ``"wa475"``), a :class:`LoaderSpec`, or λ in [0.05, 3] vs ER12.
        law: scaling law for float scales (``"product_line"`` or ``"froude"``).
        distortion: extra factors on the law (see :data:`scaletwin_envs.specs.laws.DISTORTION_KEYS`).
        soil: ``"gravel"``, ``"sand"``, ``"sandy_loam"``, ``"clay_loam"`` or a :class:`SoilSpec`.
        pile_distance: cutting edge to pile toe at reset, in boom lengths.
        pile_height: pile height, in boom lengths.
        max_episode_time: truncation, in Froude times √(L/g).
        reset_noise_scale: size of the random start pose and pile perturbations (0 = none).
        success_fill: fill factor counted as a successful dig.
        fill_reward_weight, time_cost_weight, energy_cost_weight, spill_cost_weight: reward weights.
        frame_skip, external_force_substeps: physics steps per control step / per soil-force update (None: 100 /
            20 Froude steps of 1 ms × √λ, whatever the timestep).
        timestep: physics timestep, s (None: the converged default, :func:`scaletwin_envs.builder.timestep_substeps`;
            else a finite number within 1/1000 to 2 Froude steps, or ``ValueError``).
        two_route_check: the second route to the pin forces (Newton–Euler of the linkage, never reading a pin
            constraint force; ``*_route2`` and ``residual_*`` signals): ``True`` every step, ``False`` never,
            ``None`` (default) on request: while a recorder (``EpisodeRecorder``, ``RerunLogger``, so
            ``record_episode``, sweeps, replays and ``scaletwin simulate --parquet/--rrd``) watches the env.
        render_mode, width, height: as in gymnasium's MuJoCo environments (``"human"`` needs a display).
    """

    RESET_OPTIONS: ClassVar[Mapping[str, str]] = {
        "boom_angle": "start boom angle vs the reference dig pose, rad (default U(0, 0.03)·noise)",
        "bucket_angle": "start bucket angle vs the boom, rad, within its stops (default U(-0.03, 0.03)·noise)",
        "pile_distance": "cutting edge to pile toe, boom lengths, > 0 (default pile_distance + U(-0.05, 0.05)·noise)",
        "pile_height": "pile height, boom lengths, > 0 (default pile_height·(1 + U(-0.08, 0.08)·noise))",
        "repose_angle": "pile repose angle, rad, in (0, π/2) (default the soil's ± 2°·noise)",
    }

    def __init__(
        self,
        scale: float | str | LoaderSpec = "er12",
        law: str | ScalingLaw = PRODUCT_LINE,
        distortion: Mapping[str, float] | None = None,
        soil: str | SoilSpec = "gravel",
        pile_distance: float = 0.5,
        pile_height: float = 0.7,
        max_episode_time: float = 60.0,
        reset_noise_scale: float = 1.0,
        success_fill: float = 0.85,
        fill_reward_weight: float = 1.0,
        time_cost_weight: float = 0.002,
        energy_cost_weight: float = 0.02,
        spill_cost_weight: float = 1.0,
        frame_skip: int | None = None,
        external_force_substeps: int | None = None,
        two_route_check: bool | None = None,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        timestep: float | None = None,
    ) -> None:
        self.soil = make_soil(soil)
        self.pile_distance = _positive("pile_distance", pile_distance)
        self.pile_height = _positive("pile_height", pile_height)
        self.max_episode_time = _positive("max_episode_time", max_episode_time)
        if not (math.isfinite(reset_noise_scale) and reset_noise_scale >= 0):
            raise ValueError(f"reset_noise_scale must be a finite number >= 0, got {reset_noise_scale!r}")
        self.reset_noise_scale = float(reset_noise_scale)
        self.success_fill = _positive("success_fill", success_fill)
        self.weights = {"fill": fill_reward_weight, "time": time_cost_weight, "energy": energy_cost_weight,
                        "spill": spill_cost_weight}
        for k, v in self.weights.items():
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{k} reward weight must be a finite number >= 0, got {v!r}")
        super().__init__(scale, law, distortion, frame_skip, external_force_substeps, render_mode, width, height,
                         two_route_check, timestep)
        self.observation_space = spaces.Box(-OBS_LIMIT, OBS_LIMIT, shape=(len(OBS_NAMES),), dtype=np.float32)
        L = self.loader.characteristic_length
        self.length, self.speed_scale = L, math.sqrt(GRAVITY * L)
        #: control steps after which this env truncates itself (max_episode_time in steps)
        self.horizon = math.ceil(self.max_episode_time * self.loader.froude_time / self.dt - 1e-9)
        self._sites = {n: self.model.site(n).id for n in ("bucket_edge", "bucket_heel", "bucket_back_top", "pin_O")}
        self._bucket = self.model.body("bucket").id
        self._site_ids = tuple(self._sites[n] for n in ("bucket_edge", "bucket_back_top", "bucket_heel"))
        self._cavity_ids = np.array([self._sites[n] for n in ("bucket_heel", "bucket_edge", "bucket_back_top")])
        self._site_rows = np.array(self._site_ids)
        self._curl_dofs = tuple(int(self.model.joint(n).dofadr[0]) for n in ("bucket_hinge", "boom_hinge"))
        # views of MuJoCo's arrays used several times per control step (model and data live as long as the env)
        self._site_xpos, self._xipos, self._xfrc = self.data.site_xpos, self.data.xipos, self.data.xfrc_applied
        self._tendon_damping = self.model.tendon_damping
        self._dampers = np.array([self.model.tendon(n).id for n in ("soil_damper_x", "soil_damper_z")])
        self._damper_ids = tuple(int(t) for t in self._dampers)
        self._anchors = (self.model.site("soil_anchor_x").id, self.model.site("soil_anchor_z").id)
        self._ten_velocity, self._qpos, self._qvel = self.data.ten_velocity, self.data.qpos, self.data.qvel
        # (max extend force N, stroke m, extend speed m/s) of the lift and tilt cylinders, for the observation
        self._obs_cylinders = tuple((c.max_extend_force, c.stroke, c.extend_speed)
                                    for c in (self.loader.lift, self.loader.tilt))
        self._vel6 = np.zeros(6)
        self._centroid_ends = centroid_ends(self.loader.geometry)  # load centroid, empty and heaped (m, reference pose)
        # constants read every step, worked out once (the spec's properties recompute them at each access)
        self._froude_time, self._weight = self.loader.froude_time, self.loader.weight  # s, N
        self._time_limit = self.max_episode_time * self._froude_time  # s
        self.pile: Pile
        self.dig: DigModel
        self._last_obs = np.zeros(len(OBS_NAMES), dtype=np.float32)

    # -- reset -------------------------------------------------------------------------------------------
    def _validate_reset_options(self, options: Mapping[str, Any] | None) -> dict[str, float]:
        out = super()._validate_reset_options(options)
        for k in ("pile_distance", "pile_height"):
            if k in out and out[k] <= 0:
                raise ValueError(f"reset option {k!r} must be > 0 (boom lengths), got {out[k]}")
        if "repose_angle" in out and not 0 < out["repose_angle"] < 0.5 * math.pi:
            raise ValueError(f"reset option 'repose_angle' must be in (0, pi/2) rad, got {out['repose_angle']}")
        if "boom_angle" in out or "bucket_angle" in out:
            boom, bucket = out.get("boom_angle", 0.0), out.get("bucket_angle", 0.0)
            try:
                qpos = qpos_for_pose(self.model, self.loader, solve_pose(self.loader.geometry, boom, bucket))
            except LinkageUnreachable as exc:
                raise ValueError(f"reset options boom_angle={boom}, bucket_angle={bucket} rad: {exc}") from None
            for k in ("lift", "tilt"):
                j = self._slide[k]
                lo, hi = j.range
                if not lo <= qpos[j.qposadr[0]] <= hi:
                    raise ValueError(f"reset options boom_angle={boom}, bucket_angle={bucket} rad put the {k} "
                                     f"cylinder outside its stroke")
            lo, hi = self.model.joint("bucket_hinge").range
            if not lo <= bucket <= hi:
                raise ValueError(f"reset option bucket_angle={bucket} rad lies past the bucket's stops "
                                 f"[{lo:.4g}, {hi:.4g}] rad (physics.kinematics.bucket_stops)")
        return out

    def reset_model(self) -> np.ndarray:
        rng, noise, L = self.np_random, self.reset_noise_scale, self.length
        g, opt = self.loader.geometry, self.reset_options
        boom, bucket = float(rng.uniform(0.0, 0.03) * noise), float(rng.uniform(-0.03, 0.03) * noise)
        pose = solve_pose(g, opt.get("boom_angle", boom), opt.get("bucket_angle", bucket))
        self.set_state(qpos_for_pose(self.model, self.loader, pose), np.zeros(self.model.nv))
        edge_x = float(self.data.site_xpos[self._sites["bucket_edge"]][0])
        distance = self.pile_distance + rng.uniform(-0.05, 0.05) * noise
        toe = edge_x + L * opt.get("pile_distance", distance)
        height = L * opt.get("pile_height", self.pile_height * (1.0 + rng.uniform(-0.08, 0.08) * noise))
        repose = opt.get("repose_angle", self.soil.repose_angle + math.radians(rng.uniform(-2.0, 2.0) * noise))
        self.pile = Pile(toe, height, repose, length=3.0 * L, width=g.bucket_width)
        self.dig = DigModel(self.soil, self.pile, g.bucket_width, heaped_capacity(g), L)
        for v in self.valves.values():
            v.reset()
        self._soil_force = DigForces()
        self.model.tendon_damping[self._dampers] = 0.0
        self.data.xfrc_applied[:] = 0.0
        self._work = self._reward_total = 0.0
        self._start_x = self._max_x = float(self.data.qpos[0])
        self._t = 0.0
        self._payload_volume = -1.0
        self._update_payload()
        mujoco.mj_forward(self.model, self.data)
        mujoco.mj_rnePostConstraint(self.model, self.data)
        self.signals = self._read_signals(self.soil_force())
        self._good_signals = self._step_signals()
        self._last_obs = self._get_obs()
        return self._last_obs

    def _get_reset_info(self) -> dict[str, Any]:
        return {"signals": dict(self.signals), "phase": DigPhase.IDLE.name.lower(), "loader": self.loader.name}

    # -- soil and load -----------------------------------------------------------------------------------
    def _site_xz(self, name: str) -> np.ndarray:
        p = self.data.site_xpos[self._sites[name]]
        return np.array([p[0], p[2]])

    def _apply_external_forces(self) -> None:
        """Refresh the soil resistance: the tendon dampers take the part along travel, ``xfrc_applied`` the press."""
        # plain floats (the same values as the float64 array elements) keep the scalar arithmetic below fast
        edge, top, heel = self._site_xpos.take(self._site_rows, 0).tolist()
        mujoco.mj_objectVelocity(self.model, self.data, mujoco.mjtObj.mjOBJ_SITE, self._site_ids[0], self._vel6, 0)
        _, _, _, vx, _, vz = self._vel6.tolist()
        f = self.dig.resistance((edge[0], edge[2]), (top[0], top[2]), (heel[0], heel[2]), (vx, vz))
        speed, creep = math.hypot(vx, vz), self.dig.creep
        damping = f.resist / (creep if creep > speed else speed)  # max(speed, creep), without the call
        for t in self._damper_ids:
            self._tendon_damping[t] = damping
        scale = speed / creep
        scale = scale if scale < 1.0 else 1.0
        fx, fz = scale * f.press * f.travel[1], -scale * f.press * f.travel[0]
        com_x, _, com_z = self._xipos[self._bucket].tolist()
        torque_y = (edge[2] - com_z) * fx - (edge[0] - com_x) * fz
        self._xfrc[self._bucket] = (fx, 0.0, fz, 0.0, torque_y, 0.0)  # force, torque
        self._soil_force = f

    def soil_force(self) -> np.ndarray:
        """Soil force on the bucket now (N, x–z): tendon dampers plus the press."""
        xpos = self._site_xpos
        ex, ey, ez = xpos[self._site_ids[0]].tolist()
        fx, _, fz = self._xfrc[self._bucket, :3].tolist()
        damping, velocity = self._tendon_damping, self._ten_velocity
        for t, anchor in zip(self._damper_ids, self._anchors, strict=True):
            ax, ay, az = xpos[anchor].tolist()
            ux, uy, uz = ax - ex, ay - ey, az - ez
            norm = math.sqrt(ux * ux + uy * uy + uz * uz)  # Python floats: numpy calls on 3-vectors cost more
            f = float(damping[t] * velocity[t])
            fx, fz = fx + f * (ux / norm), fz + f * (uz / norm)
        return np.array((fx, fz))

    def _after_physics(self) -> None:
        cavity = self._site_xpos.take(self._cavity_ids, 0)[:, ::2]  # heel, edge, top of back wall: x, z
        self.dig.transfer(cavity, self._bucket_pitch())
        self._update_payload()

    def _bucket_pitch(self) -> float:
        rot = self.data.xmat[self._bucket].reshape(3, 3)
        return math.atan2(rot[2, 0], rot[0, 0])

    def _update_payload(self) -> None:
        if self.dig.load_volume == self._payload_volume:
            return
        self._payload_volume = self.dig.load_volume
        (x, z), (ox, oz) = centroid_at(self._centroid_ends, self.dig.fill()), self.loader.geometry.pin_O
        set_payload(self.model, self.data, self.dig.load_mass, (x - ox, z - oz), 0.15 * self.length)

    # -- step --------------------------------------------------------------------------------------------
    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self._check_running()
        a = self._validate_action(action)
        before = {"fill": self.dig.fill(), "spill": self.dig.spilled_volume / self.dig.capacity}
        error = self._simulate(self._command_to_ctrl(a))
        dt = self.dt
        self._t += dt
        if error is None:
            sig = self._read_signals(self.soil_force())
            error = None if self._finite(sig) else "non-finite signals"
        if error is not None:
            self.sim_error = error
            return self._last_obs.copy(), 0.0, False, True, self._error_info(error)
        self.signals = sig
        qvel = self._qvel
        power = (max(sig["Pf_lift"] * float(qvel[self._slide_adr["lift"][1]]), 0.0)
                 + max(sig["Pf_tilt"] * float(qvel[self._slide_adr["tilt"][1]]), 0.0))  # W, into the cylinders
        self._work += power * dt
        self._max_x = max(self._max_x, float(self._qpos[0]))
        terms = self._reward_terms(before, power)
        reward = float(sum(terms.values()))
        self._reward_total += reward
        obs = self._get_obs()
        self._last_obs = obs
        done = self._cycle_complete()
        truncated = self._t >= self._time_limit
        info = self._step_info(terms)
        if self.render_mode == "human":
            self.render()
        return obs, reward, done, truncated and not done, info

    def _reward_terms(self, before: Mapping[str, float], power: float) -> dict[str, float]:
        w, L, dt = self.weights, self.length, self.dt
        spill = self.dig.spilled_volume / self.dig.capacity
        work_scale = self.dig.capacity * self.soil.density * GRAVITY * L  # lifting a full bucket by L
        return {
            "fill": w["fill"] * (self.dig.fill() - before["fill"]),
            "time": -w["time"] * dt / self._froude_time,
            "energy": -w["energy"] * power * dt / work_scale,
            "spill": -w["spill"] * (spill - before["spill"]),
        }

    def _edge_state(self) -> tuple[tuple[float, float], float]:
        """Cutting edge (x, z) and its depth below the pile surface, m."""
        x, _, z = self._site_xpos[self._site_ids[0]].tolist()
        return (x, z), self.pile.surface(x + 0.5 * self.pile.dx) - z

    def _cycle_complete(self) -> bool:
        _, depth = self._edge_state()
        clear = depth < -0.05 * self.length and self.signals["bucket_pitch"] > 0.2
        pulled_back = self._max_x - float(self._qpos[0]) > 0.3 * self.length
        return bool(clear and pulled_back and self.dig.load_volume > 0.0)

    def phase(self) -> DigPhase:
        _, depth = self._edge_state()
        qvel = self._qvel
        curl = float(qvel[self._curl_dofs[0]] + qvel[self._curl_dofs[1]])
        loaded = self.dig.fill() > 0.02
        return classify(depth > 0.0, curl, self.signals["travel_speed"], loaded, self.length)

    def _step_signals(self, read: Mapping[str, float] | None = None) -> dict[str, float]:
        """The step's signals: those read from the physics (``read``, default: the last read,
        :attr:`signals`) plus the load and the cylinder states now."""
        sig = dict(self.signals if read is None else read)
        sig["m_load"] = self.dig.load_mass
        sig["lift_extension"], sig["lift_speed"] = self.cylinder_state("lift")
        sig["tilt_extension"], sig["tilt_speed"] = self.cylinder_state("tilt")
        return sig

    def _step_info(self, terms: Mapping[str, float]) -> dict[str, Any]:
        sig = self._step_signals()
        self.signals = self._good_signals = sig
        fill = self.dig.fill()
        return {
            "signals": sig, "phase": self.phase().name.lower(), "reward_terms": dict(terms),
            "fill_factor": fill, "loaded_mass": self.dig.load_mass, "spilled_mass": self.dig.spilled_volume
            * self.soil.density, "hydraulic_work": self._work, "time": self._t, "success": fill >= self.success_fill,
            "sim_error": None, "action_clipped": self.action_clipped,
        }

    def _error_info(self, error: str) -> dict[str, Any]:
        """The info of a step whose physics failed: the keys of every step, the last good signals, no NaN."""

        def finite(x: float) -> float:
            return float(x) if math.isfinite(x) else 0.0

        return {
            "signals": dict(self._good_signals), "phase": "error", "reward_terms": dict.fromkeys(REWARD_TERMS, 0.0),
            "fill_factor": finite(self.dig.fill()), "loaded_mass": finite(self.dig.load_mass),
            "spilled_mass": finite(self.dig.spilled_volume * self.soil.density),
            "hydraulic_work": finite(self._work), "time": self._t, "success": False, "sim_error": error,
            "action_clipped": self.action_clipped,
        }

    # -- observation -------------------------------------------------------------------------------------
    def _get_obs(self) -> np.ndarray:
        L, sig = self.length, self.signals
        edge, depth = self._edge_state()
        lift_ext, lift_v = self.cylinder_state("lift")
        tilt_ext, tilt_v = self.cylinder_state("tilt")
        (lift_force, lift_stroke, lift_speed), (tilt_force, tilt_stroke, tilt_speed) = self._obs_cylinders
        valve_force = [self.actuator_force(k) for k in ("lift", "tilt")]  # N, the servo's output
        values = [
            sig["boom_angle"], sig["bucket_pitch"], lift_ext / lift_stroke, tilt_ext / tilt_stroke,
            lift_v / lift_speed, tilt_v / tilt_speed, sig["travel_speed"] / self.speed_scale,
            (edge[0] - float(self.pile.x[0])) / L, edge[1] / L, depth / L,
            self.pile.surface(edge[0] + 0.25 * L) / L, self.pile.surface(edge[0] + 0.5 * L) / L, self.dig.fill(),
            valve_force[0] / lift_force, valve_force[1] / tilt_force,
            math.hypot(sig["R_x"], sig["R_z"]) / self._weight,
            self._t / self._time_limit,
            self.dig.spilled_volume / self.dig.capacity, (float(self._qpos[0]) - self._start_x) / L,
        ]
        if all(map(math.isfinite, values)) and min(values) >= -OBS_LIMIT and max(values) <= OBS_LIMIT:
            return np.array(values, dtype=np.float32)  # the usual case: nothing to clip, one conversion
        obs = np.nan_to_num(np.asarray(values, dtype=np.float64), nan=0.0, posinf=OBS_LIMIT, neginf=-OBS_LIMIT)
        return np.clip(obs, -OBS_LIMIT, OBS_LIMIT).astype(np.float32)

    # -- rendering ---------------------------------------------------------------------------------------
    def render(self) -> np.ndarray | None:
        draw_pile(self.model, self.data, self.pile)
        return super().render()
