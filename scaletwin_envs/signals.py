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
force. Their difference is reported as ``residual_*`` (relative to the machine's weight). Route 2 is a check,
read when asked (``read(..., two_routes=True)``; the envs ask for it while a recorder watches them, see
:class:`scaletwin_envs.envs.loader_base.LoaderEnv`).

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
            joints=ids(mujoco.mjtObj.mjOBJ_JOINT,
                       ("drive", "boom_hinge", "bucket_hinge", "lift_cylinder", "tilt_cylinder")),
            actuators=ids(mujoco.mjtObj.mjOBJ_ACTUATOR, ("lift", "tilt", "drive")), bucket_geoms=geoms,
        )


def _point_motion(xipos: list[float], cvel: list[float], cacc: list[float], origin: list[float],
                  gravity: list[float]) -> tuple[float, float, float, float, float, float]:
    """One body's planar COM velocity (m/s) and kinematic acceleration (m/s²) in x and z, and its angular velocity
    and acceleration about MuJoCo's y axis (rad/s, rad/s²; counter-clockwise in x–z is their negative), from its
    rows of ``xipos``, ``cvel`` and ``cacc`` and the COM of its kinematic tree (``origin``, where MuJoCo takes its
    com-based spatial vectors): vel = v + w × r, acc = dv + dw × r + w × vel + g (proper → kinematic), which is what
    ``mj_objectAcceleration`` computes per body. Python floats: a dozen numpy calls on rows of three cost more."""
    x, y, z = xipos
    w0, w1, w2, c3, c4, c5 = cvel
    dw0, dw1, dw2, a3, _, a5 = cacc
    r0, r1, r2 = x - origin[0], y - origin[1], z - origin[2]
    v0, v1, v2 = c3 + (w1 * r2 - w2 * r1), c4 + (w2 * r0 - w0 * r2), c5 + (w0 * r1 - w1 * r0)
    ax = a3 + (dw1 * r2 - dw2 * r1) + (w1 * v2 - w2 * v1) + gravity[0]
    az = a5 + (dw0 * r1 - dw1 * r0) + (w0 * v1 - w1 * v0) + gravity[2]
    return v0, v2, ax, az, w1, dw1


class SignalReader:
    """Computes the signals of one loader model; call after ``mj_forward`` + ``mj_rnePostConstraint``.

    Both routes read MuJoCo's arrays through views bound once per ``MjData`` and work on Python floats (numpy's
    per-call overhead on rows of three is larger than the arithmetic): route 1 needs the motion of the bucket and
    the payload and a handful of MuJoCo's forces; route 2 the motion, mass and applied loads of every linkage body,
    from which :class:`~scaletwin_envs.physics.newton_euler.LinkageSystem` solves the pin forces.
    """

    def __init__(self, model: mujoco.MjModel, bore_areas: dict[str, tuple[float, float]], weight: float) -> None:
        self.model, self.ids = model, LoaderIds.resolve(model)
        self.bore_areas = bore_areas  # cylinder -> (piston area, annulus area), m²
        self.force_scale = weight  # N: residuals are relative to the machine's weight
        self._cforce = np.zeros(6)
        names = (*LINKAGE_BODIES, "payload")
        self._kb, self._kp = names.index("bucket"), len(names) - 1  # rows of the bucket and the payload
        self._bid = np.array([self.ids.bodies[n] for n in names])
        self._bucket, self._payload = self.ids.bodies["bucket"], self.ids.bodies["payload"]
        self._root = int(model.body_rootid[self.ids.bodies["bucket"]])
        self._sid = np.array([self.ids.sites[n] for n in PIN_SITES])
        self._pin_O = self.ids.sites["pin_O"]
        self._pin_sites = tuple(PIN_SITES.index(p) for *_, p in LINKAGE_PINS)
        self._cyl_sites = tuple((PIN_SITES.index(a), PIN_SITES.index(b)) for _, a, b in CYLINDERS)
        self.system = LinkageSystem(LINKAGE_BODIES, [(n, p, c) for n, p, c, _ in LINKAGE_PINS],
                                    [(n, f"{n}_barrel", f"{n}_rod") for n, *_ in CYLINDERS])
        pins = [n for n, *_ in LINKAGE_PINS]
        self._x21, self._xO = 2 * pins.index("pin_21"), 2 * pins.index("O")  # their x components in the solution
        self._x_axial = {c: 2 * len(pins) + 3 * k for k, (c, *_) in enumerate(CYLINDERS)}
        self._slide_dof = {k: int(model.jnt_dofadr[self.ids.joints[f"{k}_cylinder"]]) for k in ("lift", "tilt")}
        self._kboom = names.index("boom")
        self._stop_dof = int(model.jnt_dofadr[self.ids.joints["bucket_hinge"]])
        self._gravity = -float(model.opt.gravity[2])
        self._bucket_tendons = self._tendons_on(self.ids.bodies["bucket"])
        self._act = {k: self.ids.actuators[k] for k in ("lift", "tilt")}
        # Constraint servo (builder.SERVO_KINDS): the servo's force is the relief tendon's friction-loss force plus
        # the relief centre (a constant force on the slide); None with the legacy actuator servo
        relief = {k: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TENDON, f"{k}_relief") for k in ("lift", "tilt")}
        self._relief = None if min(relief.values()) < 0 else relief
        self._relief_centre = {k: float(model.actuator(f"{k}_relief_centre").biasprm[0]) for k in relief} \
            if self._relief else {}
        self._relief_rows = {"lift": 0, "tilt": 0}  # their rows at the last read (checked before use)
        self._boom_qpos = int(model.jnt_qposadr[self.ids.joints["boom_hinge"]])
        self._drive_dof = int(model.jnt_dofadr[self.ids.joints["drive"]])
        self._f21_row = 0  # first constraint row of link_b_to_bucket at the last read (checked before use)
        self._data: mujoco.MjData | None = None

    def __getstate__(self) -> dict:
        """Pickled or copied without the bound views (a copy's arrays would be detached from its ``MjData``): the
        copy binds its own at its first read."""
        state = dict(self.__dict__)
        state["_data"] = None
        for name in ("_xipos", "_cvel", "_cacc", "_subtree_com", "_xmat", "_ximat", "_site_xpos", "_cfrc_int",
                     "_actuator_force", "_xfrc", "_qpos", "_qvel", "_qacc", "_body_mass", "_gravity_vec",
                     "_dof_armature", "_dof_damping"):
            state.pop(name, None)
        return state

    def _bind(self, data: mujoco.MjData) -> None:
        """Keep views of the ``data`` arrays read every step (their memory lives as long as ``data``; the
        constraint arrays ``efc_*`` are re-allocated every step and are never kept) and of the model's (read at
        every step, so a model altered after construction is seen)."""
        if data is self._data:
            return
        self._data = data
        model = self.model
        self._body_mass, self._gravity_vec = model.body_mass, model.opt.gravity
        self._dof_armature, self._dof_damping = model.dof_armature, model.dof_damping
        self._xipos, self._cvel, self._cacc, self._subtree_com = data.xipos, data.cvel, data.cacc, data.subtree_com
        self._xmat, self._ximat, self._site_xpos, self._cfrc_int = data.xmat, data.ximat, data.site_xpos, data.cfrc_int
        self._actuator_force, self._xfrc = data.actuator_force, data.xfrc_applied
        self._qpos, self._qvel, self._qacc = data.qpos, data.qvel, data.qacc

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

    def _tendon_loads(self, data: mujoco.MjData) -> list[tuple[float, float, float, float]]:
        """Passive tendon forces on the bucket (the soil dampers; their springs are off), as (x, z, f_x, f_z) in
        m and N: damping × lengthening speed along the tendon, towards its other end."""
        loads = []
        xpos, damping, velocity = data.site_xpos, self.model.tendon_damping, data.ten_velocity
        for t, a, b in self._bucket_tendons:
            ax, ay, az = xpos[a].tolist()
            bx, by, bz = xpos[b].tolist()
            ux, uy, uz = bx - ax, by - ay, bz - az
            norm = math.sqrt(ux * ux + uy * uy + uz * uz)
            f = float(damping[t] * velocity[t])
            loads.append((ax, az, f * (ux / norm), f * (uz / norm)))
        return loads

    def _bucket_contacts(self, data: mujoco.MjData) -> list[tuple[float, float, float, float]]:
        """Contact forces on the bucket, as (x, z, f_x, f_z) in m and N."""
        loads: list[tuple[float, float, float, float]] = []
        if data.ncon == 0:
            return loads
        contact, bucket = data.contact, self.ids.bucket_geoms
        for k, (g1, g2) in enumerate(contact.geom.tolist()):
            on_g1 = g1 in bucket
            if not (on_g1 or g2 in bucket):
                continue
            mujoco.mj_contactForce(self.model, data, k, self._cforce)
            world = contact.frame[k].reshape(3, 3).T @ self._cforce[:3]  # force of geom1 on geom2
            sign = -1.0 if on_g1 else 1.0
            px, _, pz = contact.pos[k].tolist()
            loads.append((px, pz, sign * float(world[0]), sign * float(world[2])))
        return loads

    # -- signals ----------------------------------------------------------------------------------------
    def read(self, data: mujoco.MjData, soil_force: np.ndarray, two_routes: bool = True) -> dict[str, float]:
        """All signals at the current (forwarded) state; ``soil_force`` (N, x–z) is reported as ``R_x``/``R_z``.

        Applied loads enter route 2 through ``data.xfrc_applied``, contacts through MuJoCo's contact list."""
        self._bind(data)
        b, p = self._bucket, self._payload
        xipos, cvel, cacc = self._xipos, self._cvel, self._cacc
        origin, g = self._subtree_com[self._root].tolist(), self._gravity_vec.tolist()
        (cbx, cby, cbz), (cpx, cpy, cpz) = xipos[b].tolist(), xipos[p].tolist()
        vbx, vbz, abx, abz, wb, dwb = _point_motion([cbx, cby, cbz], cvel[b].tolist(), cacc[b].tolist(), origin, g)
        vpx, vpz, apx, apz, _, _ = _point_motion([cpx, cpy, cpz], cvel[p].tolist(), cacc[p].tolist(), origin, g)
        mass = self._body_mass
        mb, mp = mass.item(b), mass.item(p)
        m_b = mb + mp
        com = ((mb * cbx + mp * cpx) / m_b, (mb * cbz + mp * cpz) / m_b)
        acc = ((mb * abx + mp * apx) / m_b, (mb * abz + mp * apz) / m_b)
        vel = ((mb * vbx + mp * vpx) / m_b, (mb * vbz + mp * vpz) / m_b)
        rot = self._xmat[b]
        pitch = math.atan2(rot[6], rot[0])  # rotation matrix entries (2, 0) and (0, 0)
        ox, _, oz = self._site_xpos[self._pin_O].tolist()
        rx, rz = com[0] - ox, com[1] - oz
        c, s = math.cos(pitch), math.sin(pitch)
        f21 = self._connect_force(data)
        _, _, _, f31x, _, f31z = self._cfrc_int[b].tolist()
        actuator = {k: self.servo_force(data, k) for k in ("lift", "tilt")}
        pf = {k: actuator[k] - self._armature_force(data, k) for k in ("lift", "tilt")}  # force on the piston
        # the four magnitudes by one np.hypot call: the values np.hypot gives each (math.hypot may differ in the
        # last bit)
        f21_mag, f31_mag, a1, v1 = np.hypot((f21[0], f31x, acc[0], vel[0]), (f21[1], f31z, acc[1], vel[1])).tolist()
        out = {
            "F21": f21_mag, "F31": f31_mag, "Pf_tilt": pf["tilt"], "Pf_lift": pf["lift"],
            "x_b": c * rx + s * rz, "y_b": -s * rx + c * rz, "m_b": m_b, "a1": a1, "alpha1": abs(dwb), "V1": v1,
            "w1": abs(wb), "F21_x": f21[0], "F21_z": f21[1], "F31_x": f31x, "F31_z": f31z,
            "R_x": float(soil_force[0]), "R_z": float(soil_force[1]), "bucket_pitch": pitch,
            "boom_angle": float(self._qpos[self._boom_qpos]), "travel_speed": float(self._qvel[self._drive_dof]),
        }
        for name in ("lift", "tilt"):
            piston, annulus = self.bore_areas[name]
            out[f"p_{name}"] = pf[name] / piston if pf[name] >= 0 else -pf[name] / annulus
        if two_routes:
            out.update(self._route2(data, origin, g, f21, (f31x, f31z), actuator))
        return out

    def servo_force(self, data: mujoco.MjData, cylinder: str) -> float:
        """The servo's force on ``cylinder``'s slide (N): the relief tendon's friction-loss force (its row among the
        friction rows, which follow the equality rows) plus the relief centre; the actuator's force with the legacy
        actuator servo."""
        if self._relief is None:
            return float(data.actuator_force[self._act[cylinder]])
        t, row = self._relief[cylinder], self._relief_rows[cylinder]
        efc_id, efc_type, friction = data.efc_id, data.efc_type, mujoco.mjtConstraint.mjCNSTR_FRICTION_TENDON
        if not (row < data.nefc and efc_id[row] == t and efc_type[row] == friction):
            lo, hi = int(data.ne), int(data.ne + data.nf)
            rows = np.nonzero((efc_id[lo:hi] == t) & (efc_type[lo:hi] == friction))[0]
            if rows.size != 1:
                return self._relief_centre[cylinder]
            row = self._relief_rows[cylinder] = lo + int(rows[0])
        return float(data.efc_force[row]) + self._relief_centre[cylinder]

    def _connect_force(self, data: mujoco.MjData) -> tuple[float, float]:
        """x and z of the ``link_b_to_bucket`` connect constraint's force (N): its three rows among the equality
        rows, which MuJoCo puts first (the first ``ne``); zero when the constraint is not active."""
        ne, eq, row = int(data.ne), self.ids.eq_f21, self._f21_row
        efc_id = data.efc_id
        if not (row + 2 < ne and efc_id[row] == eq and efc_id[row + 2] == eq):  # not where it was last time
            rows = np.nonzero(efc_id[:ne] == eq)[0]
            if rows.size != 3:
                return 0.0, 0.0
            row = self._f21_row = int(rows[0])
        force = data.efc_force
        return float(force[row]), float(force[row + 2])

    def _bodies(self, origin: list[float], gravity: list[float]) -> list[tuple[float, ...]]:
        """Per linkage body and the payload (rows as ``LINKAGE_BODIES`` + payload): mass (kg), COM x, z (m), kinematic
        acceleration x, z (m/s²), angular acceleration (rad/s², CCW), inertia about the COM's y axis (kg·m²),
        applied force x, z (N) and moment (N·m, CCW) of ``xfrc_applied``."""
        b, model = self._bid, self.model
        rows = zip(self._xipos.take(b, 0).tolist(), self._cvel.take(b, 0).tolist(), self._cacc.take(b, 0).tolist(),
                   self._ximat.take(b, 0).tolist(), model.body_inertia.take(b, 0).tolist(),
                   model.body_mass.take(b).tolist(), self._xfrc.take(b, 0).tolist(), strict=True)
        out = []
        for xi, cv, ca, rot, (i0, i1, i2), m, f in rows:
            _, _, ax, az, _, dw1 = _point_motion(xi, cv, ca, origin, gravity)
            inertia = rot[3] * rot[3] * i0 + rot[4] * rot[4] * i1 + rot[5] * rot[5] * i2  # row y of the inertial frame
            out.append((m, xi[0], xi[2], ax, az, -dw1, inertia, f[0], f[2], -f[4]))
        return out

    def _route2(self, data: mujoco.MjData, origin: list[float], gravity: list[float], f21: tuple[float, float],
                f31: tuple[float, float], actuator: dict[str, float]) -> dict[str, float]:
        bodies = self._bodies(origin, gravity)
        # Merge the payload rigidly into the bucket (parallel-axis theorem) and add the bucket's contact and tendon
        # loads (applied at points: their moment about the merged COM)
        mb, cbx, cbz, abx, abz, alpha, ib, fbx, fbz, moment_b = bodies[self._kb]
        mp, cpx, cpz, apx, apz, _, ip, fpx, fpz, moment_p = bodies.pop(self._kp)
        total = mb + mp
        cx, cz = (mb * cbx + mp * cpx) / total, (mb * cbz + mp * cpz) / total
        dbx, dbz, dpx, dpz = cbx - cx, cbz - cz, cpx - cx, cpz - cz
        inertia = ib + (mb * (dbx * dbx + dbz * dbz) + ip + mp * (dpx * dpx + dpz * dpz))
        turn = moment_b + ((dpx * fpz - dpz * fpx) + moment_p + (dbx * fbz - dbz * fbx))
        fx, fz = fbx + fpx, fbz + fpz
        for px, pz, lx, lz in (*self._bucket_contacts(data), *self._tendon_loads(data)):
            fx, fz = fx + lx, fz + lz
            turn += (px - cx) * lz - (pz - cz) * lx
        # the bucket stop's moment (N·m, CCW on the bucket, the opposite on the boom; zero off the stop)
        stop = self._limit_force(data, "bucket_hinge", self._stop_dof)
        bodies[self._kb] = (total, cx, cz, (mb * abx + mp * apx) / total, (mb * abz + mp * apz) / total, alpha,
                            inertia, fx, fz, turn + stop)
        if stop:
            *boom, moment = bodies[self._kboom]
            bodies[self._kboom] = (*boom, moment - stop)
        pts = [(x, z) for x, _, z in self._site_xpos.take(self._sid, 0).tolist()]
        slide_points, slide_axes = [], []
        for a, e in self._cyl_sites:  # cylinder axis from its frame pin to its rod-end pin
            (sx, sz), (ex, ez) = pts[a], pts[e]
            dx, dz = ex - sx, ez - sz
            length = math.sqrt(dx * dx + dz * dz)
            slide_points.append((0.5 * (sx + ex), 0.5 * (sz + ez)))
            slide_axes.append((dx / length, dz / length))
        x = self.system.solve_floats(bodies, [pts[k] for k in self._pin_sites], slide_points, slide_axes,
                                     self._gravity)
        i21, iO = self._x21, self._xO
        r21, r31 = (x[i21], x[i21 + 1]), (x[iO], x[iO + 1])
        lift, tilt = x[self._x_axial["lift"]], x[self._x_axial["tilt"]]
        axial = {c_: actuator[c_] + self._limit_force(data, f"{c_}_cylinder", self._slide_dof[c_])
                 - self._armature_force(data, c_)
                 for c_ in ("lift", "tilt")}
        w = self.force_scale
        f21_r2, f31_r2, d21, d31 = np.hypot((r21[0], r31[0], r21[0] - f21[0], r31[0] - f31[0]),
                                            (r21[1], r31[1], r21[1] - f21[1], r31[1] - f31[1])).tolist()
        return {
            "F21_route2": f21_r2, "F31_route2": f31_r2, "Pf_lift_route2": lift, "Pf_tilt_route2": tilt,
            "residual_F21": d21 / w, "residual_F31": d31 / w,
            "residual_Pf_lift": abs(lift - axial["lift"]) / w, "residual_Pf_tilt": abs(tilt - axial["tilt"]) / w,
        }

    def _armature_force(self, data: mujoco.MjData, cylinder: str) -> float:
        """Slide forces MuJoCo applies in joint space only: armature inertia and viscous damping (N)."""
        dof = self._slide_dof[cylinder]
        return self._dof_armature.item(dof) * data.qacc.item(dof) + self._dof_damping.item(dof) * data.qvel.item(dof)

    def _limit_force(self, data: mujoco.MjData, joint: str, dof: int) -> float:
        """Generalised force of ``joint``'s limit on its ``dof`` (N on a slide, N·m on a hinge; 0 off its ends)."""
        if data.nl == 0:  # no joint limit active anywhere
            return 0.0
        j = self.ids.joints[joint]
        rows = np.nonzero((data.efc_type == mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT) & (data.efc_id == j))[0]
        if rows.size == 0:
            return 0.0
        # a joint-limit row's Jacobian is ±1 on the joint's dof: its sign says which end is hit
        return float(sum(data.efc_force[r] * self._jac_entry(data, r, dof) for r in rows))

    def _jac_entry(self, data: mujoco.MjData, row: int, dof: int) -> float:
        if mujoco.mj_isSparse(self.model):
            adr, nnz = data.efc_J_rowadr[row], data.efc_J_rownnz[row]
            cols = data.efc_J_colind[adr:adr + nnz]
            hit = np.nonzero(cols == dof)[0]
            return float(data.efc_J[adr + hit[0]]) if hit.size else 0.0
        return float(data.efc_J.reshape(data.nefc, self.model.nv)[row, dof])
