"""The paper's Eq. (10) and Eq. (23) signals, read from a MuJoCo loader, with every pin force by two routes.

Route 1 reads MuJoCo's constraint forces: ``F21`` from the ``link_b_to_bucket`` connect constraint, ``F31`` from
``cfrc_int`` of the bucket subtree (its interaction with the boom at O), cylinder forces ``Pf_*`` (and pressures
``p_*``) as the force the oil exerts on the piston: the actuator's force less the forces MuJoCo applies on the slide
in joint space, the armature (oil column inertia) and the damping (relief override). A velocity servo held at relief
by an overrunning load alternates between its force limits from one physics step to the next while the slide's
inertia absorbs the difference, so the bare actuator force, sampled once per control step, says nothing of the pin
forces (it was up to 14× off on holds); the piston force is smooth, and it is what a pressure transducer on the
cylinder reads. Route 2 is the planar Newton–Euler of the linkage (:mod:`scaletwin_envs.physics.newton_euler`) from
kinematics, masses and the applied loads alone (gravity, soil, ground contact), never looking at a pin constraint
force. Their difference is reported as ``residual_*`` (relative to the machine's weight).

All signals are SI: forces N, lengths m, mass kg, accelerations m/s² (kinematic, not proper), angular accelerations
rad/s², velocities m/s and rad/s. Planar vectors are (x forward, z up) in the world frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from scaletwin_envs.physics.newton_euler import LinkageSystem
from scaletwin_envs.physics.statics import CYLINDERS, LINKAGE_PINS

LINKAGE_BODIES = ("boom", "bucket", "bell_crank", "link_b", "lift_barrel", "lift_rod", "tilt_barrel", "tilt_rod")
PIN_SITES = tuple(sorted({p for *_, p in LINKAGE_PINS} | {"bucket_edge", "bucket_heel", "bucket_back_top"}))


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


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (n, 3) arrays (np.cross is several times slower on small arrays)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def _xz(v: np.ndarray) -> np.ndarray:
    return np.array([v[0], v[2]])


class SignalReader:
    """Computes the signals of one loader model; call after ``mj_forward`` + ``mj_rnePostConstraint``.

    Kinematics of all linkage bodies are read in one vectorised pass from MuJoCo's com-based spatial
    velocities and accelerations (``cvel``, ``cacc``), which is what ``mj_objectAcceleration`` does per body.
    """

    def __init__(self, model: mujoco.MjModel, bore_areas: dict[str, tuple[float, float]], weight: float) -> None:
        self.model, self.ids = model, LoaderIds.resolve(model)
        self.bore_areas = bore_areas  # cylinder -> (piston area, annulus area), m²
        self.force_scale = weight  # N: residuals are relative to the machine's weight
        self._cforce = np.zeros(6)
        self._names = (*LINKAGE_BODIES, "payload")
        self._kb, self._kp = self._names.index("bucket"), len(self._names) - 1  # rows of the bucket and the payload
        self._bid = np.array([self.ids.bodies[n] for n in self._names])
        self._root = int(model.body_rootid[self.ids.bodies["bucket"]])
        self._sid = np.array([self.ids.sites[n] for n in PIN_SITES])
        self._pin_sites = np.array([PIN_SITES.index(p) for *_, p in LINKAGE_PINS])
        self._cyl_sites = np.array([[PIN_SITES.index(a), PIN_SITES.index(b)] for _, a, b in CYLINDERS])
        self.system = LinkageSystem(LINKAGE_BODIES, [(n, p, c) for n, p, c, _ in LINKAGE_PINS],
                                    [(n, f"{n}_barrel", f"{n}_rod") for n, *_ in CYLINDERS])
        self._slide_dof = {k: int(model.jnt_dofadr[self.ids.joints[f"{k}_cylinder"]]) for k in ("lift", "tilt")}
        self._gravity = -float(model.opt.gravity[2])
        self._bucket_tendons = self._tendons_on(self.ids.bodies["bucket"])

    def _tendons_on(self, body: int) -> list[tuple[int, int, int]]:
        """Two-site spatial tendons starting on ``body``: (tendon, site on body, other site)."""
        m, out = self.model, []
        for t in range(m.ntendon):
            adr, num = m.tendon_adr[t], m.tendon_num[t]
            if num == 2 and all(m.wrap_type[adr + k] == mujoco.mjtWrap.mjWRAP_SITE for k in range(2)):
                a, b = int(m.wrap_objid[adr]), int(m.wrap_objid[adr + 1])
                if m.site_bodyid[a] == body:
                    out.append((t, a, b))
        return out

    def _tendon_loads(self, data: mujoco.MjData) -> list[tuple[np.ndarray, np.ndarray]]:
        """Passive tendon forces (damping) on the bucket, as (point, force) in x–z."""
        loads = []
        xpos, m = data.site_xpos, self.model
        for t, a, b in self._bucket_tendons:
            u = xpos[b] - xpos[a]
            u = u / math.sqrt(u.dot(u))  # np.linalg.norm of a vector, without its call overhead
            f = m.tendon_damping[t] * data.ten_velocity[t] - m.tendon_stiffness[t] * (
                data.ten_length[t] - m.tendon_lengthspring[t, 0]) * 0.0
            loads.append((_xz(xpos[a]), f * _xz(u)))
        return loads

    def _kinematics(self, data: mujoco.MjData) -> dict[str, np.ndarray]:
        """Planar COM position, velocity, kinematic acceleration, angular velocity/acceleration (CCW) per body."""
        # Each MjData/MjModel attribute access and fancy index costs about a microsecond: read each array once, and
        # form only the x and z components of the acceleration (same operations, in the same order, as the full
        # 3-vector expression acc = dv + dw × r + w × vel + g, so the values are bit for bit those of that form).
        b, model = self._bid, self.model
        xipos, cvel, cacc = data.xipos[b], data.cvel[b], data.cacc[b]
        r = xipos - data.subtree_com[self._root]
        w = cvel[:, :3]
        vel = cvel[:, 3:] + _cross(w, r)
        w0, w1, w2, dw0, dw1, dw2 = w[:, 0], w[:, 1], w[:, 2], cacc[:, 0], cacc[:, 1], cacc[:, 2]
        r0, r1, r2, v0, v1, v2 = r[:, 0], r[:, 1], r[:, 2], vel[:, 0], vel[:, 1], vel[:, 2]
        g = model.opt.gravity
        acc = np.empty((len(b), 2))
        acc[:, 0] = cacc[:, 3] + (dw1 * r2 - dw2 * r1) + (w1 * v2 - w2 * v1) + g[0]  # proper → kinematic
        acc[:, 1] = cacc[:, 5] + (dw0 * r1 - dw1 * r0) + (w0 * v1 - w1 * v0) + g[2]
        rot_y = data.ximat[b][:, 3:6]  # row y of each body's inertial frame
        inertia = (rot_y**2 * model.body_inertia[b]).sum(axis=1)
        xfrc = data.xfrc_applied[b]
        return {"com": xipos[:, [0, 2]], "vel": vel[:, [0, 2]], "acc": acc, "omega": -w1, "alpha": -dw1,
                "mass": model.body_mass[b], "inertia": inertia, "force": xfrc[:, [0, 2]], "moment": -xfrc[:, 4]}

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
    def read(self, data: mujoco.MjData, soil_force: np.ndarray, two_routes: bool = True) -> dict[str, float]:
        """All signals at the current (forwarded) state; ``soil_force`` (N, x–z) is reported as ``R_x``/``R_z``.

        Applied loads enter route 2 through ``data.xfrc_applied``, contacts through MuJoCo's contact list."""
        ids, m = self.ids, self.model
        k = self._kinematics(data)
        kb, kp = self._kb, self._kp
        mb, mp = k["mass"][kb], k["mass"][kp]
        m_b = mb + mp
        com = (mb * k["com"][kb] + mp * k["com"][kp]) / m_b
        acc = (mb * k["acc"][kb] + mp * k["acc"][kp]) / m_b
        vel = (mb * k["vel"][kb] + mp * k["vel"][kp]) / m_b
        rot = data.xmat[ids.bodies["bucket"]].reshape(3, 3)
        pitch = math.atan2(rot[2, 0], rot[0, 0])
        r = com - _xz(data.site_xpos[ids.sites["pin_O"]])
        c, s = math.cos(pitch), math.sin(pitch)
        f21 = self._connect_force(data)
        f31 = _xz(data.cfrc_int[ids.bodies["bucket"]][3:])
        actuator = {c_: float(data.actuator_force[ids.actuators[c_]]) for c_ in ("lift", "tilt")}
        pf = {c_: actuator[c_] - self._armature_force(data, c_) for c_ in ("lift", "tilt")}  # force on the piston
        out = {
            "F21": float(np.hypot(*f21)), "F31": float(np.hypot(*f31)), "Pf_tilt": pf["tilt"], "Pf_lift": pf["lift"],
            "x_b": c * r[0] + s * r[1], "y_b": -s * r[0] + c * r[1], "m_b": float(m_b),
            "a1": float(np.hypot(*acc)), "alpha1": abs(float(k["alpha"][kb])), "V1": float(np.hypot(*vel)),
            "w1": abs(float(k["omega"][kb])), "F21_x": f21[0], "F21_z": f21[1], "F31_x": f31[0], "F31_z": f31[1],
            "R_x": float(soil_force[0]), "R_z": float(soil_force[1]), "bucket_pitch": pitch,
            "boom_angle": float(data.qpos[m.jnt_qposadr[ids.joints["boom_hinge"]]]),
            "travel_speed": float(data.qvel[m.jnt_dofadr[ids.joints["drive"]]]),
        }
        for name in ("lift", "tilt"):
            piston, annulus = self.bore_areas[name]
            out[f"p_{name}"] = pf[name] / piston if pf[name] >= 0 else -pf[name] / annulus
        if two_routes:
            out.update(self._route2(data, k, f21, f31, actuator))
        return out

    def _connect_force(self, data: mujoco.MjData) -> np.ndarray:
        ne = int(data.ne)  # MuJoCo orders constraint rows equality first: the first ne rows
        rows = np.nonzero(data.efc_id[:ne] == self.ids.eq_f21)[0]
        if rows.size != 3:
            return np.zeros(2)
        force = data.efc_force
        return np.array([force[rows[0]], force[rows[2]]])

    def _route2(self, data: mujoco.MjData, k: dict[str, np.ndarray], f21: np.ndarray, f31: np.ndarray,
                actuator: dict[str, float]) -> dict[str, float]:
        kb, kp = self._kb, self._kp
        n = kp  # linkage bodies only; the payload is merged into the bucket
        mass, com, inertia = k["mass"][:n].copy(), k["com"][:n].copy(), k["inertia"][:n].copy()
        acc, force, moment = k["acc"][:n].copy(), k["force"][:n].copy(), k["moment"][:n].copy()
        # Merge the payload rigidly into the bucket (parallel-axis theorem) and add the bucket's contact and tendon
        # loads. Done on Python floats: the same operations, in the same order, as on the 2-vectors (so bit for bit
        # the same values), at a fraction of the cost of numpy calls on arrays of two.
        mb, mp = float(mass[kb]), float(k["mass"][kp])
        (cbx, cbz), (cpx, cpz) = com[kb].tolist(), k["com"][kp].tolist()
        (abx, abz), (apx, apz) = acc[kb].tolist(), k["acc"][kp].tolist()
        (fbx, fbz), (fpx, fpz) = force[kb].tolist(), k["force"][kp].tolist()
        total = mb + mp
        cx, cz = (mb * cbx + mp * cpx) / total, (mb * cbz + mp * cpz) / total
        dbx, dbz, dpx, dpz = cbx - cx, cbz - cz, cpx - cx, cpz - cz
        inertia[kb] = float(inertia[kb]) + (
            mb * (dbx * dbx + dbz * dbz) + float(k["inertia"][kp]) + mp * (dpx * dpx + dpz * dpz))
        acc[kb] = ((mb * abx + mp * apx) / total, (mb * abz + mp * apz) / total)
        turn = float(moment[kb]) + ((dpx * fpz - dpz * fpx) + float(k["moment"][kp]) + (dbx * fbz - dbz * fbx))
        fx, fz = fbx + fpx, fbz + fpz
        for point, f in (*self._bucket_contacts(data), *self._tendon_loads(data)):
            (px, pz), (lx, lz) = point.tolist(), f.tolist()
            fx, fz = fx + lx, fz + lz
            turn += (px - cx) * lz - (pz - cz) * lx
        mass[kb], com[kb], force[kb], moment[kb] = total, (cx, cz), (fx, fz), turn
        pts = data.site_xpos[self._sid][:, [0, 2]]
        starts, ends = pts[self._cyl_sites[:, 0]], pts[self._cyl_sites[:, 1]]
        axes = (ends - starts) / np.linalg.norm(ends - starts, axis=1, keepdims=True)
        sol = self.system.solve(mass, com, inertia, acc, k["alpha"][:n], force, moment, pts[self._pin_sites],
                                0.5 * (starts + ends), axes, self._gravity)
        r21, r31 = sol.pins["pin_21"], sol.pins["O"]
        axial = {c_: actuator[c_] + self._limit_force(data, c_) - self._armature_force(data, c_)
                 for c_ in ("lift", "tilt")}
        w = self.force_scale
        return {
            "F21_route2": float(np.hypot(*r21)), "F31_route2": float(np.hypot(*r31)),
            "Pf_lift_route2": sol.axial["lift"], "Pf_tilt_route2": sol.axial["tilt"],
            "residual_F21": float(np.hypot(*(r21 - f21))) / w, "residual_F31": float(np.hypot(*(r31 - f31))) / w,
            "residual_Pf_lift": abs(sol.axial["lift"] - axial["lift"]) / w,
            "residual_Pf_tilt": abs(sol.axial["tilt"] - axial["tilt"]) / w,
        }

    def _armature_force(self, data: mujoco.MjData, cylinder: str) -> float:
        """Slide forces MuJoCo applies in joint space only: armature inertia and viscous damping (N)."""
        dof = self._slide_dof[cylinder]
        return float(self.model.dof_armature[dof] * data.qacc[dof] + self.model.dof_damping[dof] * data.qvel[dof])

    def _limit_force(self, data: mujoco.MjData, cylinder: str) -> float:
        j = self.ids.joints[f"{cylinder}_cylinder"]
        if data.nl == 0:  # no joint limit active anywhere
            return 0.0
        rows = np.nonzero((data.efc_type == mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT) & (data.efc_id == j))[0]
        if rows.size == 0:
            return 0.0
        # a joint-limit row's Jacobian is ±1 on the joint's dof: its sign says which end is hit
        dof = self._slide_dof[cylinder]
        return float(sum(data.efc_force[r] * self._jac_entry(data, r, dof) for r in rows))

    def _jac_entry(self, data: mujoco.MjData, row: int, dof: int) -> float:
        if mujoco.mj_isSparse(self.model):
            adr, nnz = data.efc_J_rowadr[row], data.efc_J_rownnz[row]
            cols = data.efc_J_colind[adr:adr + nnz]
            hit = np.nonzero(cols == dof)[0]
            return float(data.efc_J[adr + hit[0]]) if hit.size else 0.0
        return float(data.efc_J.reshape(data.nefc, self.model.nv)[row, dof])
