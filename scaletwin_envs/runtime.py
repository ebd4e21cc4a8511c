"""Runtime edits of a built loader model: assemble a pose, carry a load, draw the pile.

These write into a compiled model/data pair produced by :mod:`scaletwin_envs.builder` and rely on its names.
"""

from __future__ import annotations

import mujoco
import numpy as np

from scaletwin_envs.builder import PILE_COLUMNS, xz_to_xyz
from scaletwin_envs.physics.kinematics import LinkagePose
from scaletwin_envs.physics.mass_layout import cylinder_axis
from scaletwin_envs.physics.pile import Pile
from scaletwin_envs.specs.loader import LoaderSpec


def qpos_for_pose(model: mujoco.MjModel, spec: LoaderSpec, pose: LinkagePose, drive: float = 0.0) -> np.ndarray:
    """Joint positions that assemble ``pose`` exactly (every loop closed)."""
    _, lift_ref = cylinder_axis(spec, "lift")
    _, tilt_ref = cylinder_axis(spec, "tilt")
    values = {
        "drive": drive, "boom_hinge": pose.boom, "bucket_hinge": pose.bucket, "bell_crank_hinge": pose.bell_crank,
        "link_b_hinge": pose.link_b, "lift_barrel_hinge": pose.lift_angle, "lift_cylinder": pose.lift_length - lift_ref,
        "tilt_barrel_hinge": pose.tilt_angle, "tilt_cylinder": pose.tilt_length - tilt_ref,
    }
    qpos = model.qpos0.copy()
    for name, v in values.items():
        qpos[model.joint(name).qposadr[0]] = v
    return qpos


def set_payload(model: mujoco.MjModel, data: mujoco.MjData, mass: float, com_local: np.ndarray | tuple[float, float],
                radius_of_gyration: float) -> None:
    """Write the load carried by the bucket into the ``payload`` body (kg, m relative to O) and refresh
    MuJoCo's derived constants. A floor of 1e-9 × bucket mass keeps the body well defined when empty."""
    b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "payload")
    floor = 1e-9 * float(model.body_mass[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "bucket")])
    m = max(mass, floor)
    model.body_mass[b] = m
    model.body_ipos[b] = xz_to_xyz(com_local)
    model.body_inertia[b] = m * radius_of_gyration**2
    qpos = data.qpos.copy()  # mj_setConst leaves qpos at qpos0
    mujoco.mj_setConst(model, data)
    data.qpos[:] = qpos


def draw_pile(model: mujoco.MjModel, data: mujoco.MjData, pile: Pile) -> None:
    """Move the ``pile_*`` boxes to show the pile's current surface (visual only, no collision)."""
    x, h = pile.x, pile.h
    edges = np.linspace(x[0], x[-1], PILE_COLUMNS + 1)
    floor = 1e-4 * float(x[-1] - x[0])
    for k in range(PILE_COLUMNS):
        sel = (x >= edges[k]) & (x <= edges[k + 1])
        height = max(float(h[sel].mean()) if sel.any() else 0.0, floor)
        gid = model.geom(f"pile_{k}").id
        model.geom_size[gid][0] = 0.5 * (edges[k + 1] - edges[k])
        model.geom_size[gid][2] = 0.5 * height
        model.geom_pos[gid] = (0.5 * (edges[k] + edges[k + 1]), 0.0, 0.5 * height)
        data.geom_xpos[gid] = model.geom_pos[gid]  # world geoms: kinematics would only copy it at the next step
        # the renderer culls by these bounds, which the compiler sized for the initial tiny boxes
        model.geom_rbound[gid] = float(np.linalg.norm(model.geom_size[gid]))
        model.geom_aabb[gid, 3:] = model.geom_size[gid]
