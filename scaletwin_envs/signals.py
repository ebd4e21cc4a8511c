"""The paper's Eq. (10) and Eq. (23) signals, read from a MuJoCo loader, with every pin force by two routes.

Route 1 reads MuJoCo's constraint forces: ``F21`` from the ``link_b_to_bucket`` connect constraint, ``F31``
from ``cfrc_int`` of the bucket subtree (its interaction with the boom at O), cylinder forces from the
actuators. Route 2 is the planar Newton–Euler of the linkage (:mod:`scaletwin_envs.physics.newton_euler`)
from kinematics, masses and the applied loads alone (gravity, soil, ground contact), never looking at a pin
constraint force. Their difference is reported as ``residual_*`` (relative to the machine's weight).

All signals are SI: forces N, lengths m, mass kg, accelerations m/s² (kinematic, not proper), angular
accelerations rad/s², velocities m/s and rad/s. Planar vectors are (x forward, z up) in the world frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from scaletwin_envs.physics.newton_euler import PlanarBody, solve_joint_forces
from scaletwin_envs.physics.statics import LINKAGE_PINS, combine, linkage_joints

LINKAGE_BODIES = ("boom", "bucket", "bell_crank", "link_b", "lift_barrel", "lift_rod", "tilt_barrel", "tilt_rod")
PIN_SITES = tuple(sorted({p for *_, p in LINKAGE_PINS} | {"bucket_edge", "bucket_heel", "bucket_back_top"}))
EQ10 = ("F21", "F31", "Pf_tilt", "Pf_lift", "x_b", "y_b", "m_b", "a1", "alpha1")
EQ23 = ("F21", "F31", "Pf_tilt", "Pf_lift", "x_b", "y_b", "m_b", "V1", "w1")

#: Unit of every signal key (SI), used by recordings and importers.
SIGNAL_UNITS: dict[str, str] = {
    "F21": "N", "F31": "N", "Pf_tilt": "N", "Pf_lift": "N", "x_b": "m", "y_b": "m", "m_b": "kg",
    "a1": "m/s^2", "alpha1": "rad/s^2", "V1": "m/s", "w1": "rad/s",
    "F21_x": "N", "F21_z": "N", "F31_x": "N", "F31_z": "N", "R_x": "N", "R_z": "N",
    "p_lift": "Pa", "p_tilt": "Pa", "lift_extension": "m", "tilt_extension": "m",
    "lift_speed": "m/s", "tilt_speed": "m/s", "travel_speed": "m/s", "boom_angle": "rad", "bucket_pitch": "rad",
    "m_load": "kg", "F21_route2": "N", "F31_route2": "N", "Pf_lift_route2": "N", "Pf_tilt_route2": "N",
    "residual_F21": "1", "residual_F31": "1", "residual_Pf_lift": "1", "residual_Pf_tilt": "1",
}


@dataclass(frozen=True)
class LoaderIds:
    """MuJoCo ids resolved once per model."""

    bodies: dict[str, int]
    sites: dict[str, int]
    eq_f21: int
    joints: dict[str, int]
    actuators: dict[str, int]
    bucket_geoms: frozenset[int]

    @classmethod
    def resolve(cls, model: mujoco.MjModel) -> LoaderIds:
        def ids(kind: mujoco.mjtObj, names: tuple[str, ...]) -> dict[str, int]:
            out = {n: mujoco.mj_name2id(model, kind, n) for n in names}
            missing = [n for n, i in out.items() if i < 0]
            if missing:
                raise ValueError(f"loader model lacks {kind.name} {missing}")
            return out

        bodies = ids(mujoco.mjtObj.mjOBJ_BODY, (*LINKAGE_BODIES, "payload", "frame"))
        geoms = frozenset(int(g) for g in np.nonzero(model.geom_bodyid == bodies["bucket"])[0])
        return cls(
            bodies=bodies, sites=ids(mujoco.mjtObj.mjOBJ_SITE, (*PIN_SITES, "pin_O")),
            eq_f21=ids(mujoco.mjtObj.mjOBJ_EQUALITY, ("link_b_to_bucket",))["link_b_to_bucket"],
            joints=ids(mujoco.mjtObj.mjOBJ_JOINT, ("drive", "boom_hinge", "lift_cylinder", "tilt_cylinder")),
            actuators=ids(mujoco.mjtObj.mjOBJ_ACTUATOR, ("lift", "tilt", "drive")), bucket_geoms=geoms,
        )


def _xz(v: np.ndarray) -> np.ndarray:
    return np.array([v[0], v[2]])


class SignalReader:
    """Computes the signals of one loader model; call after ``mj_forward`` + ``mj_rnePostConstraint``."""

    def __init__(self, model: mujoco.MjModel, bore_areas: dict[str, tuple[float, float]], weight: float) -> None:
        self.model, self.ids = model, LoaderIds.resolve(model)
        self.bore_areas = bore_areas  # cylinder -> (piston area, annulus area), m²
        self.force_scale = weight  # N: residuals are relative to the machine's weight
        self._acc, self._vel = np.zeros(6), np.zeros(6)
        self._cforce = np.zeros(6)

    # -- kinematics -------------------------------------------------------------------------------------
    def _body_state(self, data: mujoco.MjData, body: int) -> tuple[np.ndarray, float, np.ndarray, float]:
        """Kinematic COM acceleration (x, z), angular acceleration (CCW), COM velocity, angular velocity."""
        mujoco.mj_objectAcceleration(self.model, data, mujoco.mjtObj.mjOBJ_BODY, body, self._acc, 0)
        mujoco.mj_objectVelocity(self.model, data, mujoco.mjtObj.mjOBJ_BODY, body, self._vel, 0)
        acc = _xz(self._acc[3:]) + _xz(self.model.opt.gravity)  # proper → kinematic
        return acc, -float(self._acc[1]), _xz(self._vel[3:]), -float(self._vel[1])

    def _planar_body(self, data: mujoco.MjData, name: str) -> PlanarBody:
        """The body's planar mass properties, kinematics and applied wrench (``xfrc_applied``, at its COM)."""
        b = self.ids.bodies[name]
        rot = data.ximat[b].reshape(3, 3)
        inertia = float(rot[1] @ (self.model.body_inertia[b] * rot[1]))
        acc, alpha, _, _ = self._body_state(data, b)
        com = _xz(data.xipos[b])
        xfrc = data.xfrc_applied[b]
        return PlanarBody(name, float(self.model.body_mass[b]), com, inertia, acc, alpha,
                          loads=[(com, _xz(xfrc[:3]))], moment=-float(xfrc[4]))

    def _bucket_contacts(self, data: mujoco.MjData) -> list[tuple[np.ndarray, np.ndarray]]:
        loads = []
        for k in range(data.ncon):
            c = data.contact[k]
            on_g1 = int(c.geom1) in self.ids.bucket_geoms
            if not (on_g1 or int(c.geom2) in self.ids.bucket_geoms):
                continue
            mujoco.mj_contactForce(self.model, data, k, self._cforce)
            world = c.frame.reshape(3, 3).T @ self._cforce[:3]  # force of geom1 on geom2
            loads.append((_xz(c.pos), _xz(-world if on_g1 else world)))
        return loads

    # -- signals ----------------------------------------------------------------------------------------
    def read(self, data: mujoco.MjData, soil_force: np.ndarray) -> dict[str, float]:
        """All signals at the current (forwarded) state; ``soil_force`` (N, x–z) is reported as ``R_x``/``R_z``.

        Applied loads enter route 2 through ``data.xfrc_applied``, contacts through MuJoCo's contact list."""
        ids, m = self.ids, self.model
        bucket = combine(self._planar_body(data, "bucket"), self._planar_body(data, "payload"))
        rot = data.xmat[ids.bodies["bucket"]].reshape(3, 3)
        pitch = math.atan2(rot[2, 0], rot[0, 0])
        o = _xz(data.site_xpos[ids.sites["pin_O"]])
        c, s = math.cos(-pitch), math.sin(-pitch)
        r = bucket.com - o
        vel, omega = self._combined_velocity(data)
        f21 = self._connect_force(data)
        f31 = _xz(data.cfrc_int[ids.bodies["bucket"]][3:])
        pf = {k: float(data.actuator_force[ids.actuators[k]]) for k in ("lift", "tilt")}
        out = {
            "F21": float(np.hypot(*f21)), "F31": float(np.hypot(*f31)), "Pf_tilt": pf["tilt"], "Pf_lift": pf["lift"],
            "x_b": c * r[0] - s * r[1], "y_b": s * r[0] + c * r[1], "m_b": bucket.mass,
            "a1": float(np.hypot(*bucket.acc)), "alpha1": abs(bucket.alpha), "V1": float(np.hypot(*vel)),
            "w1": abs(omega), "F21_x": f21[0], "F21_z": f21[1], "F31_x": f31[0], "F31_z": f31[1],
            "R_x": float(soil_force[0]), "R_z": float(soil_force[1]), "bucket_pitch": pitch,
            "boom_angle": float(data.qpos[m.jnt_qposadr[ids.joints["boom_hinge"]]]),
            "travel_speed": float(data.qvel[m.jnt_dofadr[ids.joints["drive"]]]),
        }
        for k in ("lift", "tilt"):
            piston, annulus = self.bore_areas[k]
            out[f"p_{k}"] = pf[k] / piston if pf[k] >= 0 else -pf[k] / annulus
        out.update(self._route2(data, bucket, f21, f31, pf))
        return out

    def _combined_velocity(self, data: mujoco.MjData) -> tuple[np.ndarray, float]:
        total, mom = 0.0, np.zeros(2)
        omega = 0.0
        for name in ("bucket", "payload"):
            b = self.ids.bodies[name]
            _, _, v, w = self._body_state(data, b)
            mass = float(self.model.body_mass[b])
            total += mass
            mom += mass * v
            omega = w if name == "bucket" else omega
        return mom / total, omega

    def _connect_force(self, data: mujoco.MjData) -> np.ndarray:
        rows = np.nonzero((data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY) & (data.efc_id == self.ids.eq_f21))[0]
        return np.array([data.efc_force[rows[0]], data.efc_force[rows[2]]]) if rows.size == 3 else np.zeros(2)

    def _route2(self, data: mujoco.MjData, bucket: PlanarBody, f21: np.ndarray, f31: np.ndarray,
                pf: dict[str, float]) -> dict[str, float]:
        bodies = [bucket if n == "bucket" else self._planar_body(data, n) for n in LINKAGE_BODIES]
        bucket.loads.extend(self._bucket_contacts(data))
        points = {n: _xz(data.site_xpos[self.ids.sites[n]]) for n in PIN_SITES}
        pins, slides = linkage_joints(points)
        sol = solve_joint_forces(bodies, pins, slides, gravity=-float(self.model.opt.gravity[2]))
        r21, r31 = sol.pins["pin_21"], sol.pins["O"]
        axial = {k: pf[k] + self._limit_force(data, k) - self._armature_force(data, k) for k in ("lift", "tilt")}
        w = self.force_scale
        return {
            "F21_route2": float(np.hypot(*r21)), "F31_route2": float(np.hypot(*r31)),
            "Pf_lift_route2": sol.axial["lift"], "Pf_tilt_route2": sol.axial["tilt"],
            "residual_F21": float(np.hypot(*(r21 - f21))) / w, "residual_F31": float(np.hypot(*(r31 - f31))) / w,
            "residual_Pf_lift": abs(sol.axial["lift"] - axial["lift"]) / w,
            "residual_Pf_tilt": abs(sol.axial["tilt"] - axial["tilt"]) / w,
        }

    def _armature_force(self, data: mujoco.MjData, cylinder: str) -> float:
        dof = self.model.jnt_dofadr[self.ids.joints[f"{cylinder}_cylinder"]]
        return float(self.model.dof_armature[dof] * data.qacc[dof])

    def _limit_force(self, data: mujoco.MjData, cylinder: str) -> float:
        j = self.ids.joints[f"{cylinder}_cylinder"]
        rows = (data.efc_type == mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT) & (data.efc_id == j)
        if not rows.any():
            return 0.0
        # a limit row's force acts along the joint, signed by its Jacobian entry
        dof = self.model.jnt_dofadr[j]
        return float(np.sum(data.efc_force[rows] * self._efc_jac_entries(data, rows, dof)))

    def _efc_jac_entries(self, data: mujoco.MjData, rows: np.ndarray, dof: int) -> np.ndarray:
        if mujoco.mj_isSparse(self.model):
            out = []
            for r in np.nonzero(rows)[0]:
                adr, n = data.efc_J_rowadr[r], data.efc_J_rownnz[r]
                cols = data.efc_J_colind[adr:adr + n]
                vals = data.efc_J[adr:adr + n]
                out.append(float(vals[cols == dof][0]) if (cols == dof).any() else 0.0)
            return np.asarray(out)
        return data.efc_J.reshape(data.nefc, self.model.nv)[rows, dof]
