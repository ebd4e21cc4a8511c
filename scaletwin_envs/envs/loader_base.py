"""A thin Gymnasium base for MuJoCo wheel loaders built procedurally from a :class:`LoaderSpec`.

It owns what every loader task shares: building the model at any scale, turning normalised commands into
cylinder and drive speeds, stepping the physics with a hook for external forces between physics blocks,
reading the Eq. (10)/(23) signals, and catching numerical blow-ups. Tasks override the hooks
``_reset_task``, ``_apply_external_forces``, ``_after_physics``, ``_get_obs``, ``_reward`` and
``_terminated``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, ClassVar

import mujoco
import numpy as np
from gymnasium import spaces
from gymnasium.envs.mujoco.mujoco_env import MujocoEnv

from scaletwin_envs.builder import BuildOptions, build_model
from scaletwin_envs.envs.hydraulics import CylinderValve
from scaletwin_envs.signals import SignalReader
from scaletwin_envs.specs.laws import PRODUCT_LINE, ScalingLaw
from scaletwin_envs.specs.loader import LoaderSpec, make_loader

DEFAULT_FRAME_SKIP = 100  # 10 Hz control at the ER12 (100 ms × √λ)
DEFAULT_EXTERNAL_FORCE_SUBSTEPS = 20  # soil resistance refreshed every 20 ms × √λ (it acts through implicit dampers)


class LoaderEnv(MujocoEnv):
    """Base class: a loader of any size with lift, tilt and drive commands in [-1, 1]."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array", "depth_array"]}

    def __init__(
        self,
        scale: float | str | LoaderSpec = "er12",
        law: str | ScalingLaw = PRODUCT_LINE,
        distortion: Mapping[str, float] | None = None,
        frame_skip: int = DEFAULT_FRAME_SKIP,
        external_force_substeps: int = DEFAULT_EXTERNAL_FORCE_SUBSTEPS,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        two_route_check: bool = True,
    ) -> None:
        self.loader = make_loader(scale, law, distortion)
        for name, value in (("frame_skip", frame_skip), ("external_force_substeps", external_force_substeps)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        if frame_skip % external_force_substeps:
            raise ValueError(f"frame_skip ({frame_skip}) must be a multiple of external_force_substeps "
                             f"({external_force_substeps})")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.build_options = BuildOptions.for_spec(self.loader)
        self.external_force_substeps = external_force_substeps
        self.two_route_check = two_route_check
        dt = self.build_options.timestep * frame_skip
        self.metadata = {**type(self).metadata, "render_fps": int(np.round(1.0 / dt))}
        MujocoEnv.__init__(self, model_path=__file__, frame_skip=frame_skip, observation_space=None,
                           render_mode=render_mode, width=width, height=height, camera_name="side")
        self.signal_reader = SignalReader(self.model, {
            "lift": (self.loader.lift.bore_area, self.loader.lift.annulus_area),
            "tilt": (self.loader.tilt.bore_area, self.loader.tilt.annulus_area)}, self.loader.weight)
        self._slide = {k: self.model.joint(f"{k}_cylinder") for k in ("lift", "tilt")}
        self.valves = {k: CylinderValve(getattr(self.loader, k), *self._slide[k].range,
                                        hold_time=0.2 * self.loader.froude_time) for k in ("lift", "tilt")}
        self.signals: dict[str, float] = {}

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
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action must be finite, got {a.tolist()}")
        return np.clip(a, -1.0, 1.0)

    def _command_to_ctrl(self, a: np.ndarray) -> np.ndarray:
        ctrl = np.zeros(3)
        for i, k in enumerate(("lift", "tilt")):
            ctrl[i] = self.valves[k].speed(float(a[i]), float(self.data.qpos[self._slide[k].qposadr[0]]))
        ctrl[2] = float(a[2]) * self.loader.travel_speed
        return ctrl

    # -- stepping ----------------------------------------------------------------------------------------
    def _simulate(self, ctrl: np.ndarray) -> str | None:
        """Advance one control step; returns an error message if the physics blew up."""
        self.data.ctrl[:] = ctrl
        warnings_before = self._bad_state_warnings()
        for _ in range(self.frame_skip // self.external_force_substeps):
            self._apply_external_forces()
            mujoco.mj_step(self.model, self.data, nstep=self.external_force_substeps)
        if self._bad_state_warnings() > warnings_before:  # MuJoCo resets a diverged state silently; don't hide it
            return "MuJoCo reported a non-finite or huge state (physics diverged)"
        if not (np.all(np.isfinite(self.data.qpos)) and np.all(np.isfinite(self.data.qvel))):
            return "non-finite state (physics diverged)"
        self._after_physics()
        mujoco.mj_forward(self.model, self.data)
        mujoco.mj_rnePostConstraint(self.model, self.data)
        return None

    def _read_signals(self, soil_force: np.ndarray) -> dict[str, float]:
        return self.signal_reader.read(self.data, soil_force, two_routes=self.two_route_check)

    def _bad_state_warnings(self) -> int:
        w = self.data.warning
        return sum(int(w[k].number) for k in (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
                                               mujoco.mjtWarning.mjWARN_BADQACC))

    def actuator_force(self, which: str) -> float:
        """The valve's force on ``"lift"`` or ``"tilt"`` (N) at the last physics step: the servo's output, which
        at relief may alternate between its limits step by step (observations keep it, as the policies were trained
        on it; the ``Pf_*`` signals report the piston force, see :mod:`scaletwin_envs.signals`)."""
        return float(self.data.actuator_force[self.signal_reader.ids.actuators[which]])

    def cylinder_state(self, which: str) -> tuple[float, float]:
        """Extension from fully retracted (m) and speed (m/s) of ``"lift"`` or ``"tilt"``."""
        j = self._slide[which]
        return (float(self.data.qpos[j.qposadr[0]] - j.range[0]), float(self.data.qvel[j.dofadr[0]]))

    # -- hooks -------------------------------------------------------------------------------------------
    def _apply_external_forces(self) -> None:
        """Called before each block of ``external_force_substeps`` physics steps."""

    def _after_physics(self) -> None:
        """Called after the physics of a control step, before signals are read."""

    @staticmethod
    def _finite(values: Mapping[str, float]) -> bool:
        return all(math.isfinite(v) for v in values.values())
