"""WheelLoaderDig-v0: a wheel loader of any size fills its bucket from a soil pile.

The machine (:mod:`scaletwin_envs.builder`) drives straight at a pile (:mod:`scaletwin_envs.physics.pile`)
whose resistance follows the fundamental earthmoving equation (:mod:`scaletwin_envs.physics.dig`); material
inside the bucket cavity becomes part of the combined bucket + load body, whose mass and centre of mass
change as it fills and spills. Every step logs the paper's Eq. (10) and Eq. (23) signals in
``info["signals"]`` (SI), with each pin force obtained by two independent routes.

Action: ``[lift, tilt, drive]`` in [-1, 1]; positive raises the boom, curls the bucket back, drives forward;
0 holds. Observation: dimensionless (lengths / boom length L, speeds / √(gL), forces / weight or relief
force, time / max episode time), so one policy acts at every scale; names in :data:`OBS_NAMES`.
Reward: fill gained (fraction of heaped capacity) minus time, hydraulic energy and spill costs; each term in
``info["reward_terms"]``. The episode terminates when the loaded bucket has been lifted clear of the pile and
the machine has pulled back (``info["success"]`` if the fill factor reaches ``success_fill``), and is truncated
at ``max_episode_time`` (Froude time units) or on a physics blow-up (``info["sim_error"]``).

Version history:
    v0: initial release (scaletwin 0.1).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import mujoco
import numpy as np
from gymnasium import spaces

from scaletwin_envs.envs.loader_base import DEFAULT_EXTERNAL_FORCE_SUBSTEPS, DEFAULT_FRAME_SKIP, LoaderEnv
from scaletwin_envs.envs.phases import DigPhase, classify
from scaletwin_envs.physics.bucket import load_centroid
from scaletwin_envs.physics.dig import DigForces, DigModel
from scaletwin_envs.physics.kinematics import solve_pose
from scaletwin_envs.physics.pile import Pile
from scaletwin_envs.runtime import draw_pile, qpos_for_pose, set_payload
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
        frame_skip, external_force_substeps: physics steps per control step / per soil-force update.
        two_route_check: also solve the Newton–Euler route every step (``*_route2``, ``residual_*`` signals).
        render_mode, width, height: as in gymnasium's MuJoCo environments.
    """

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
        frame_skip: int = DEFAULT_FRAME_SKIP,
        external_force_substeps: int = DEFAULT_EXTERNAL_FORCE_SUBSTEPS,
        two_route_check: bool = True,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
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
                         two_route_check)
        self.observation_space = spaces.Box(-OBS_LIMIT, OBS_LIMIT, shape=(len(OBS_NAMES),), dtype=np.float32)
        L = self.loader.characteristic_length
        self.length, self.speed_scale = L, math.sqrt(GRAVITY * L)
        self._sites = {n: self.model.site(n).id for n in ("bucket_edge", "bucket_heel", "bucket_back_top", "pin_O")}
        self._bucket = self.model.body("bucket").id
        self._site_ids = tuple(self._sites[n] for n in ("bucket_edge", "bucket_back_top", "bucket_heel"))
        self._dampers = np.array([self.model.tendon(n).id for n in ("soil_damper_x", "soil_damper_z")])
        self._anchors = (self.model.site("soil_anchor_x").id, self.model.site("soil_anchor_z").id)
        self._vel6 = np.zeros(6)
        self.pile: Pile
        self.dig: DigModel
        self._last_obs = np.zeros(len(OBS_NAMES), dtype=np.float32)

    # -- reset -------------------------------------------------------------------------------------------
    def reset_model(self) -> np.ndarray:
        rng, noise, L = self.np_random, self.reset_noise_scale, self.length
        g = self.loader.geometry
        pose = solve_pose(g, float(rng.uniform(0.0, 0.03) * noise), float(rng.uniform(-0.03, 0.03) * noise))
        self.set_state(qpos_for_pose(self.model, self.loader, pose), np.zeros(self.model.nv))
        edge_x = float(self.data.site_xpos[self._sites["bucket_edge"]][0])
        toe = edge_x + L * (self.pile_distance + rng.uniform(-0.05, 0.05) * noise)
        height = L * self.pile_height * (1.0 + rng.uniform(-0.08, 0.08) * noise)
        repose = self.soil.repose_angle + math.radians(rng.uniform(-2.0, 2.0) * noise)
        self.pile = Pile(toe, height, repose, length=3.0 * L, width=g.bucket_width)
        self.dig = DigModel(self.soil, self.pile, g.bucket_width, self.loader.heaped_capacity, L)
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
        sx, ids = self.data.site_xpos, self._site_ids
        edge, top, heel = sx[ids[0]], sx[ids[1]], sx[ids[2]]
        mujoco.mj_objectVelocity(self.model, self.data, mujoco.mjtObj.mjOBJ_SITE, ids[0], self._vel6, 0)
        vx, vz = self._vel6[3], self._vel6[5]
        f = self.dig.resistance((edge[0], edge[2]), (top[0], top[2]), (heel[0], heel[2]), (vx, vz))
        speed = math.hypot(vx, vz)
        self.model.tendon_damping[self._dampers] = f.resist / max(speed, self.dig.creep)
        scale = min(1.0, speed / self.dig.creep)
        fx, fz = scale * f.press * f.travel[1], -scale * f.press * f.travel[0]
        com = self.data.xipos[self._bucket]
        torque_y = (edge[2] - com[2]) * fx - (edge[0] - com[0]) * fz
        self.data.xfrc_applied[self._bucket] = (fx, 0.0, fz, 0.0, torque_y, 0.0)  # force, torque
        self._soil_force = f

    def soil_force(self) -> np.ndarray:
        """Soil force on the bucket now (N, x–z): tendon dampers plus the press."""
        edge = self.data.site_xpos[self._site_ids[0]]
        total = self.data.xfrc_applied[self._bucket][[0, 2]].copy()
        for t, anchor in zip(self._dampers, self._anchors, strict=True):
            u = self.data.site_xpos[anchor] - edge
            u = u / np.linalg.norm(u)
            total += self.model.tendon_damping[t] * self.data.ten_velocity[t] * u[[0, 2]]
        return total

    def _after_physics(self) -> None:
        cavity = np.array([self._site_xz(n) for n in ("bucket_heel", "bucket_edge", "bucket_back_top")])
        self.dig.transfer(cavity, self._bucket_pitch())
        self._update_payload()

    def _bucket_pitch(self) -> float:
        rot = self.data.xmat[self._bucket].reshape(3, 3)
        return math.atan2(rot[2, 0], rot[0, 0])

    def _update_payload(self) -> None:
        if self.dig.load_volume == self._payload_volume:
            return
        self._payload_volume = self.dig.load_volume
        g = self.loader.geometry
        fill = self.dig.fill()
        com = load_centroid(g, fill) - np.asarray(g.pin_O)
        set_payload(self.model, self.data, self.dig.load_mass, com, 0.15 * self.length)

    # -- step --------------------------------------------------------------------------------------------
    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        a = self._validate_action(action)
        before = {"fill": self.dig.fill(), "spill": self.dig.spilled_volume / self.dig.capacity}
        error = self._simulate(self._command_to_ctrl(a))
        self._t += self.dt
        if error is None:
            sig = self._read_signals(self.soil_force())
            error = None if self._finite(sig) else "non-finite signals"
        if error is not None:
            info = {"signals": dict(self.signals), "sim_error": error, "phase": "error", "success": False,
                    "reward_terms": {}}
            return self._last_obs.copy(), 0.0, False, True, info
        self.signals = sig
        power = sum(max(sig[f"Pf_{k}"] * self.cylinder_state(k)[1], 0.0) for k in ("lift", "tilt"))
        self._work += power * self.dt
        self._max_x = max(self._max_x, float(self.data.qpos[0]))
        terms = self._reward_terms(before, power)
        reward = float(sum(terms.values()))
        self._reward_total += reward
        obs = self._get_obs()
        self._last_obs = obs
        done = self._cycle_complete()
        truncated = self._t >= self.max_episode_time * self.loader.froude_time
        info = self._step_info(terms)
        if self.render_mode == "human":
            self.render()
        return obs, reward, done, truncated and not done, info

    def _reward_terms(self, before: Mapping[str, float], power: float) -> dict[str, float]:
        w, L = self.weights, self.length
        spill = self.dig.spilled_volume / self.dig.capacity
        work_scale = self.dig.capacity * self.soil.density * GRAVITY * L  # lifting a full bucket by L
        return {
            "fill": w["fill"] * (self.dig.fill() - before["fill"]),
            "time": -w["time"] * self.dt / self.loader.froude_time,
            "energy": -w["energy"] * power * self.dt / work_scale,
            "spill": -w["spill"] * (spill - before["spill"]),
        }

    def _edge_state(self) -> tuple[np.ndarray, float]:
        edge = self._site_xz("bucket_edge")
        return edge, self.pile.surface(edge[0] + 0.5 * self.pile.dx) - edge[1]

    def _cycle_complete(self) -> bool:
        _, depth = self._edge_state()
        clear = depth < -0.05 * self.length and self.signals["bucket_pitch"] > 0.2
        pulled_back = self._max_x - float(self.data.qpos[0]) > 0.3 * self.length
        return bool(clear and pulled_back and self.dig.load_volume > 0.0)

    def phase(self) -> DigPhase:
        _, depth = self._edge_state()
        curl = float(self.data.qvel[self.model.joint("bucket_hinge").dofadr[0]]
                     + self.data.qvel[self.model.joint("boom_hinge").dofadr[0]])
        loaded = self.dig.fill() > 0.02
        return classify(depth > 0.0, curl, self.signals["travel_speed"], loaded, self.length)

    def _step_info(self, terms: Mapping[str, float]) -> dict[str, Any]:
        sig = dict(self.signals)
        sig["m_load"] = self.dig.load_mass
        sig["lift_extension"], sig["lift_speed"] = self.cylinder_state("lift")
        sig["tilt_extension"], sig["tilt_speed"] = self.cylinder_state("tilt")
        self.signals = sig
        fill = self.dig.fill()
        return {
            "signals": sig, "phase": self.phase().name.lower(), "reward_terms": dict(terms),
            "fill_factor": fill, "loaded_mass": self.dig.load_mass, "spilled_mass": self.dig.spilled_volume
            * self.soil.density, "hydraulic_work": self._work, "time": self._t, "success": fill >= self.success_fill,
            "sim_error": None,
        }

    # -- observation -------------------------------------------------------------------------------------
    def _get_obs(self) -> np.ndarray:
        L, sig = self.length, self.signals
        edge, depth = self._edge_state()
        lift_ext, lift_v = self.cylinder_state("lift")
        tilt_ext, tilt_v = self.cylinder_state("tilt")
        lift, tilt = self.loader.lift, self.loader.tilt
        values = (
            sig["boom_angle"], sig["bucket_pitch"], lift_ext / lift.stroke, tilt_ext / tilt.stroke,
            lift_v / lift.extend_speed, tilt_v / tilt.extend_speed, sig["travel_speed"] / self.speed_scale,
            (edge[0] - self.pile.x[0]) / L, edge[1] / L, depth / L,
            self.pile.surface(edge[0] + 0.25 * L) / L, self.pile.surface(edge[0] + 0.5 * L) / L, self.dig.fill(),
            self.actuator_force("lift") / lift.max_extend_force, self.actuator_force("tilt") / tilt.max_extend_force,
            math.hypot(sig["R_x"], sig["R_z"]) / self.loader.weight,
            self._t / (self.max_episode_time * self.loader.froude_time),
            self.dig.spilled_volume / self.dig.capacity, (float(self.data.qpos[0]) - self._start_x) / L,
        )
        obs = np.nan_to_num(np.asarray(values, dtype=np.float64), nan=0.0, posinf=OBS_LIMIT, neginf=-OBS_LIMIT)
        return np.clip(obs, -OBS_LIMIT, OBS_LIMIT).astype(np.float32)

    # -- rendering ---------------------------------------------------------------------------------------
    def render(self) -> np.ndarray | None:
        draw_pile(self.model, self.data, self.pile)
        return super().render()
