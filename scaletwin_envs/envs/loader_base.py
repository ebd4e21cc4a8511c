"""A thin Gymnasium base for MuJoCo wheel loaders built procedurally from a :class:`LoaderSpec`.

It owns what every loader task shares: building the model at any scale, turning normalised commands into
cylinder and drive speeds, stepping the physics with a hook for external forces between physics blocks,
reading the Eq. (10)/(23) signals, and catching numerical blow-ups. Tasks override the hooks
``_reset_task``, ``_apply_external_forces``, ``_after_physics``, ``_get_obs``, ``_reward`` and
``_terminated``; tasks that accept ``reset(options=...)`` list them in :attr:`LoaderEnv.RESET_OPTIONS`.

Gymnasium conventions every loader shares:

* actions outside [-1, 1] are clipped, as gymnasium's MuJoCo v5 environments do (MuJoCo clamps their ``ctrl``
  to ``ctrlrange`` silently); here the step's ``info["action_clipped"]`` says whether it happened;
* after a step that ended in a simulation error (``info["sim_error"]``), stepping again without ``reset`` raises
  :class:`EpisodeFinishedError`: MuJoCo has reset the diverged state, so carrying on would silently continue
  from a state the policy never saw;
* the second, independent route to the pin forces (Newton–Euler of the linkage, the ``*_route2`` and
  ``residual_*`` signals) is a check, computed on request: ``two_route_check=True`` every step, ``False`` never, and
  ``None`` (the default) only while a recorder watches the env (:class:`~scaletwin_envs.recording.recorder.
  EpisodeRecorder`, :class:`~scaletwin_envs.recording.rerun_log.RerunLogger`, which call
  :meth:`LoaderEnv.request_two_route_check`), so recordings, sweeps and replays carry both routes while plain
  stepping (training, rollouts) skips the solve (a quarter of the env's own time per step, 6 % of ``env.step``);
* ``render_mode="human"`` needs a display: without one (Linux without ``DISPLAY``/``WAYLAND_DISPLAY``, or
  ``MUJOCO_GL=egl``/``osmesa``) the constructor raises ``ValueError`` instead of the GL library aborting the
  process, and ``"human"`` is left out of the instance's ``metadata["render_modes"]`` (so gymnasium's
  ``check_env`` tries only the modes that can work here).
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Mapping
from typing import Any, ClassVar

import mujoco
import numpy as np
from gymnasium import spaces
from gymnasium.envs.mujoco.mujoco_env import MujocoEnv

from scaletwin_envs.builder import BuildOptions, build_model, froude_timestep, supply_dofs
from scaletwin_envs.envs.hydraulics import CylinderValve
from scaletwin_envs.signals import SignalReader
from scaletwin_envs.specs import make_loader
from scaletwin_envs.specs.laws import PRODUCT_LINE, ScalingLaw, make_law
from scaletwin_envs.specs.loader import LoaderSpec

# Control step and soil refresh period in Froude steps (1 ms × √λ, builder.froude_timestep), whatever the physics
# timestep: frame_skip and external_force_substeps default to these periods counted in physics steps (× the
# builder's substeps, e.g. 300 and 60 at the mini), so the control rate is the same in Froude time at every scale.
DEFAULT_FRAME_SKIP = 100  # 10 Hz control at the ER12 (100 ms × √λ)
DEFAULT_EXTERNAL_FORCE_SUBSTEPS = 20  # soil resistance refreshed every 20 ms × √λ (it acts through implicit dampers)
#: MUJOCO_GL back ends that render off-screen only (no window can open).
HEADLESS_GL = ("egl", "osmesa")


class EpisodeFinishedError(RuntimeError):
    """``step`` was called on an episode that ended in a simulation error; call ``reset`` first."""


def display_available() -> bool:
    """Whether a ``render_mode="human"`` window can open: always on macOS/Windows; on Linux an X11 or Wayland
    display (``DISPLAY``/``WAYLAND_DISPLAY``) and a MuJoCo GL back end that is not off-screen only."""
    if os.environ.get("MUJOCO_GL", "").lower() in HEADLESS_GL:
        return False
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class LoaderEnv(MujocoEnv):
    """Base class: a loader of any size with lift, tilt and drive commands in [-1, 1]."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array", "depth_array"]}
    #: ``reset(options=...)`` keys this env accepts → what they set (any other key raises ``ValueError``).
    RESET_OPTIONS: ClassVar[Mapping[str, str]] = {}
    #: How the cylinders' velocity servos and relief valves are modelled (builder.SERVO_KINDS)
    SERVO: ClassVar[str] = "constraint"

    def __init__(
        self,
        scale: float | str | LoaderSpec = "er12",
        law: str | ScalingLaw = PRODUCT_LINE,
        distortion: Mapping[str, float] | None = None,
        frame_skip: int | None = None,
        external_force_substeps: int | None = None,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        two_route_check: bool | None = None,
        timestep: float | None = None,
    ) -> None:
        if not isinstance(scale, int | float) and make_law(law) != PRODUCT_LINE:
            raise ValueError(f"law={law!r} applies to float scales only; scale={scale!r} is a fixed machine (a preset "
                             "or a LoaderSpec): pass a length ratio to build it on that law")
        self.loader = make_loader(scale, law, distortion)
        self.build_options = BuildOptions.for_spec(self.loader, timestep, self._tilt_armature_factor(), self.SERVO)
        frame_skip = self._steps_in("frame_skip", frame_skip, DEFAULT_FRAME_SKIP)
        external_force_substeps = self._steps_in("external_force_substeps", external_force_substeps,
                                                 DEFAULT_EXTERNAL_FORCE_SUBSTEPS)
        for name, value in (("frame_skip", frame_skip), ("external_force_substeps", external_force_substeps)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        if frame_skip % external_force_substeps:
            raise ValueError(f"frame_skip ({frame_skip}) must be a multiple of external_force_substeps "
                             f"({external_force_substeps})")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        headless = not display_available()
        if render_mode == "human" and headless:
            raise ValueError("render_mode='human' needs a display, and none is available (no DISPLAY or "
                             "WAYLAND_DISPLAY, or MUJOCO_GL=egl/osmesa): use render_mode='rgb_array' and save or "
                             "stream the frames, or record the episode (scaletwin simulate --rrd) and open it "
                             "with scaletwin view")
        self.external_force_substeps = external_force_substeps
        if two_route_check is not None and not isinstance(two_route_check, bool | np.bool_):
            raise ValueError(f"two_route_check must be True, False or None (on request), got {two_route_check!r}")
        self.two_route_check = None if two_route_check is None else bool(two_route_check)
        self._two_routes = self.two_route_check is True  # whether signals include route 2 now
        dt = self.build_options.timestep * frame_skip
        modes = [m for m in type(self).metadata["render_modes"] if not (headless and m == "human")]
        self.metadata = {**type(self).metadata, "render_modes": modes, "render_fps": int(np.round(1.0 / dt))}
        MujocoEnv.__init__(self, model_path=__file__, frame_skip=frame_skip, observation_space=None,
                           render_mode=render_mode, width=width, height=height, camera_name="side")
        self.signal_reader = SignalReader(self.model, {
            "lift": (self.loader.lift.bore_area, self.loader.lift.annulus_area),
            "tilt": (self.loader.tilt.bore_area, self.loader.tilt.annulus_area)}, self.loader.weight)
        self._slide = {k: self.model.joint(f"{k}_cylinder") for k in ("lift", "tilt")}
        # (qpos address, dof address, lower end of travel) per cylinder: read every step, resolved once
        self._slide_adr = {k: (int(j.qposadr[0]), int(j.dofadr[0]), float(j.range[0])) for k, j in self._slide.items()}
        self._supply = supply_dofs(self.model, self.loader)
        self._warnings = tuple(int(w) for w in (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
                                                 mujoco.mjtWarning.mjWARN_BADQACC))
        self.valves = {k: CylinderValve(getattr(self.loader, k), *self._slide[k].range,
                                        hold_time=0.2 * self.loader.froude_time) for k in ("lift", "tilt")}
        self.signals: dict[str, float] = {}
        self.action_clipped = False  # whether the last action had a component outside [-1, 1]
        self.sim_error: str | None = None  # why the episode ended in a simulation error (None: it did not)
        self.reset_options: dict[str, float] = {}  # the validated options of the last reset

    # -- reset -------------------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        """Gymnasium reset; ``options`` may hold the keys of :attr:`RESET_OPTIONS` (validated, then available to
        ``reset_model`` as :attr:`reset_options`)."""
        self.reset_options = self._validate_reset_options(options)
        self.sim_error = None
        return super().reset(seed=seed, options=options)

    def _validate_reset_options(self, options: Mapping[str, Any] | None) -> dict[str, float]:
        """Check ``options`` against :attr:`RESET_OPTIONS`: known keys, finite numbers (subclasses check ranges)."""
        if options is None:
            return {}
        if not isinstance(options, Mapping):
            raise ValueError(f"reset options must be a dict, got {type(options).__name__}")
        unknown = sorted(set(options) - set(self.RESET_OPTIONS))
        if unknown:
            accepted = ", ".join(f"{k} ({v})" for k, v in self.RESET_OPTIONS.items()) or "none"
            raise ValueError(f"unknown reset option(s) {unknown}; accepted: {accepted}")
        out = {}
        for k, v in options.items():
            if isinstance(v, bool) or not isinstance(v, int | float | np.floating | np.integer) or not math.isfinite(v):
                raise ValueError(f"reset option {k!r} must be a finite number, got {v!r}")
            out[k] = float(v)
        return out

    def _check_running(self) -> None:
        """Raise :class:`EpisodeFinishedError` if the episode ended in a simulation error (call at each step)."""
        if self.sim_error is not None:
            raise EpisodeFinishedError(f"the episode ended in a simulation error ({self.sim_error}); call reset() "
                                       "before stepping again (gymnasium: step after the end of an episode needs "
                                       "a reset)")

    def _tilt_armature_factor(self) -> float:
        """Factor on the tilt slide's armature that this env builds (the timestep rule reads the inertia as built)."""
        return 1.0

    def _steps_in(self, name: str, value: int | None, froude_steps: int) -> int | None:
        """``value`` as given; None: ``froude_steps`` Froude steps counted in physics steps at this env's timestep,
        which must divide that period (else ``ValueError``: pass ``name`` explicitly)."""
        if value is not None:
            return value
        steps = froude_steps * froude_timestep(self.loader) / self.build_options.timestep
        if abs(steps - round(steps)) > 1e-6 * steps:
            raise ValueError(f"timestep={self.build_options.timestep!r} s does not divide the default period of "
                             f"{froude_steps} Froude steps ({froude_steps * froude_timestep(self.loader):.6g} s): "
                             f"pass {name} (physics steps) as well")
        return round(steps)

    # -- MujocoEnv plumbing ------------------------------------------------------------------------------
    def _initialize_simulation(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        model = build_model(self.loader, self.build_options)
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, self.width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, self.height)
        return model, mujoco.MjData(model)

    def _set_action_space(self) -> spaces.Box:
        self.action_space = spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        return self.action_space

    # -- commands ----------------------------------------------------------------------------------------
    def _validate_action(self, action: Any) -> np.ndarray:
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (3,):
            raise ValueError(f"action must have shape (3,) = [lift, tilt, drive] in [-1, 1], got shape {a.shape}")
        values = a.tolist()  # three Python floats: cheaper to check and clip than numpy calls on three elements
        if not all(map(math.isfinite, values)):
            raise ValueError(f"action must be finite, got {values}")
        self.action_clipped = not (min(values) >= -1.0 and max(values) <= 1.0)
        return np.array([min(max(v, -1.0), 1.0) for v in values] if self.action_clipped else values)

    def _command_to_ctrl(self, a: np.ndarray) -> np.ndarray:
        lift, tilt, drive = a.tolist()
        qpos = self.data.qpos
        return np.array((self.valves["lift"].speed(lift, float(qpos[self._slide_adr["lift"][0]])),
                         self.valves["tilt"].speed(tilt, float(qpos[self._slide_adr["tilt"][0]])),
                         drive * self.loader.travel_speed))

    # -- stepping ----------------------------------------------------------------------------------------
    def _simulate(self, ctrl: np.ndarray) -> str | None:
        """Advance one control step; returns an error message if the physics blew up."""
        self.data.ctrl[:3] = ctrl
        if self._supply:  # the valve is a velocity source (builder.SUPPLY_TIME): start it at its speed
            qvel, (lift, tilt, _) = self.data.qvel, ctrl.tolist()
            (lift_dof, lift_shift), (tilt_dof, tilt_shift) = self._supply
            qvel[lift_dof], qvel[tilt_dof] = lift - lift_shift, tilt - tilt_shift
        warnings_before = self._bad_state_warnings()
        for k in range(self.frame_skip // self.external_force_substeps):
            if k:  # mj_step leaves the kinematics of the start of its last step: the soil must see the state now
                if self._bad_state_warnings() > warnings_before:  # not the soil force of a diverged state
                    break
                self._refresh_kinematics()
            self._apply_external_forces()
            mujoco.mj_step(self.model, self.data, nstep=self.external_force_substeps)
        if self._bad_state_warnings() > warnings_before:  # MuJoCo resets a diverged state silently; don't hide it
            return "MuJoCo reported a non-finite or huge state (physics diverged)"
        if not (all(map(math.isfinite, self.data.qpos.tolist())) and all(map(math.isfinite, self.data.qvel.tolist()))):
            return "non-finite state (physics diverged)"
        self._after_physics()
        mujoco.mj_forward(self.model, self.data)
        mujoco.mj_rnePostConstraint(self.model, self.data)
        return None

    def _refresh_kinematics(self) -> None:
        """Body and site poses and velocities at the current state (``mj_step`` leaves those of the start of its last
        step, one timestep old). Without it a soil refresh inside a control step read the edge one step late while
        the first one (after the previous step's ``mj_forward``) read it on time, so the dig depended on the control
        step: the same commands at a fifth of it moved F21 by 0.9 % RMS (4 % at worst) of its range at the ER12 and
        2.2 % (13 %) at the WA475; with it the two are the same to the last bit."""
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)
        mujoco.mj_comVel(self.model, self.data)

    def _read_signals(self, soil_force: np.ndarray) -> dict[str, float]:
        return self.signal_reader.read(self.data, soil_force, two_routes=self._two_routes)

    @property
    def computes_two_routes(self) -> bool:
        """Whether the signals include route 2 (``*_route2``, ``residual_*``) now."""
        return self._two_routes

    def request_two_route_check(self) -> bool:
        """Compute route 2 from the next signal read on, unless the env was made with ``two_route_check=False``;
        returns whether it is on. Recorders call it before the reset of the episode they record."""
        if self.two_route_check is None:
            self._two_routes = True
        return self._two_routes

    def _bad_state_warnings(self) -> int:
        number = self.data.warning.number.tolist()
        return sum(number[k] for k in self._warnings)

    def actuator_force(self, which: str) -> float:
        """The valve's force on ``"lift"`` or ``"tilt"`` (N) at the last physics step: the servo's output (the
        relief tendon's force plus the relief centre; with the legacy actuator servo the actuator's force, which at
        relief may alternate between its limits step by step). The ``Pf_*`` signals report the piston force (this
        less the slide's armature and damping forces), see :mod:`scaletwin_envs.signals`."""
        return self.signal_reader.servo_force(self.data, which)

    def cylinder_state(self, which: str) -> tuple[float, float]:
        """Extension from fully retracted (m) and speed (m/s) of ``"lift"`` or ``"tilt"``."""
        qpos_adr, dof, lower = self._slide_adr[which]
        return self.data.qpos.item(qpos_adr) - lower, self.data.qvel.item(dof)

    # -- hooks -------------------------------------------------------------------------------------------
    def _apply_external_forces(self) -> None:
        """Called before each block of ``external_force_substeps`` physics steps."""

    def _after_physics(self) -> None:
        """Called after the physics of a control step, before signals are read."""

    @staticmethod
    def _finite(values: Mapping[str, float]) -> bool:
        return all(map(math.isfinite, values.values()))
