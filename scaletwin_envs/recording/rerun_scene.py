"""The loader in 3D for rerun: static geometry once per body, then only body transforms, the pile and the load.

Geometry is read from the compiled MuJoCo model (``model.geom_*``: capsules, cylinders, boxes and spheres) and
logged once, as static data, under ``/world/loader/<body>/geometry`` in the body frame; per step only
``rr.Transform3D`` of ``/world/loader/<body>`` changes (world pose from ``data.xpos``/``data.xquat``). The
world's own geoms (ground plane, pile columns) are not logged: the pile is drawn as its surface profile.
"""

from __future__ import annotations

import math
from typing import Any

import mujoco
import numpy as np
import rerun as rr

WORLD_PATH = "/world"
LOADER_PATH = "/world/loader"
PILE_PATH = "/world/pile"
LOAD_PATH = "/world/bucket_load"
_PILE_COLORS = np.array([0x8C6B40FF, 0x8C6B40FF], dtype=np.uint32)  # packed RGBA, one per strip
_LOAD_COLOR = (0.85, 0.55, 0.15, 1.0)


def _xyzw(wxyz: np.ndarray) -> np.ndarray:
    """MuJoCo quaternions (w, x, y, z) → rerun order (x, y, z, w), row-wise."""
    q = np.asarray(wxyz, dtype=np.float64).reshape(-1, 4)
    return q[:, [1, 2, 3, 0]]


def _rotate(wxyz: np.ndarray, v: np.ndarray) -> np.ndarray:
    out = np.zeros(3)
    mujoco.mju_rotVecQuat(out, np.asarray(v, dtype=np.float64), np.asarray(wxyz, dtype=np.float64))
    return out


class SceneLogger:
    """Logs one MuJoCo model's bodies; build once per model, then call the ``log_*`` methods."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        with_geoms = sorted({int(b) for b in model.geom_bodyid if b > 0})
        self.body_ids = np.array(with_geoms, dtype=np.intp)
        self.paths = [f"{LOADER_PATH}/{model.body(b).name or f'body{b}'}" for b in with_geoms]
        payload = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "payload")
        self.payload = payload if payload >= 0 else None

    # -- static -------------------------------------------------------------------------------------------
    def log_geometry(self, rec: rr.RecordingStream) -> None:
        """Static: view coordinates (z up) and every body's geoms in its own frame."""
        rec.log(WORLD_PATH, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for body, path in zip(self.body_ids, self.paths, strict=True):
            for kind, parts in self.body_geometry(int(body)).items():
                rec.log(f"{path}/geometry/{kind}", _archetype(kind, parts), static=True)

    def body_geometry(self, body: int) -> dict[str, list[dict[str, Any]]]:
        """The body's geoms by kind, in the body frame: ``geom`` (id), ``pos`` (m; a capsule's start, else its
        centre), ``quat`` (MuJoCo w, x, y, z), ``rgba``, and ``r``/``len`` (m) or ``half`` (half sizes, m)."""
        m = self.model
        parts: dict[str, list[dict[str, Any]]] = {"capsules": [], "cylinders": [], "boxes": [], "spheres": []}
        for g in np.nonzero(m.geom_bodyid == body)[0]:
            kind, size, pos, quat = int(m.geom_type[g]), m.geom_size[g], m.geom_pos[g], m.geom_quat[g]
            item = {"geom": int(g), "quat": quat, "rgba": m.geom_rgba[g]}
            if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:  # rerun capsules start at their translation, along +z
                parts["capsules"].append({**item, "r": size[0], "len": 2 * size[1],
                                          "pos": pos - _rotate(quat, np.array([0.0, 0.0, size[1]]))})
            elif kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
                parts["cylinders"].append({**item, "r": size[0], "len": 2 * size[1], "pos": pos})
            elif kind == mujoco.mjtGeom.mjGEOM_BOX:
                parts["boxes"].append({**item, "half": size.copy(), "pos": pos})
            elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
                parts["spheres"].append({**item, "half": np.full(3, size[0]), "pos": pos})
        return {k: v for k, v in parts.items() if v}

    # -- per step -----------------------------------------------------------------------------------------
    def poses(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """World positions (bodies, 3) in m and quaternions (bodies, 4) in rerun's xyzw order."""
        return data.xpos[self.body_ids].copy(), _xyzw(data.xquat[self.body_ids])

    def send_poses(self, rec: rr.RecordingStream, indexes: list[rr.TimeColumn], positions: np.ndarray,
                   quaternions: np.ndarray) -> None:
        """Send buffered poses, shapes (steps, bodies, 3) and (steps, bodies, 4), as one column per body."""
        for k, path in enumerate(self.paths):
            rec.send_columns(path, indexes=indexes, columns=rr.Transform3D.columns(
                translation=positions[:, k], quaternion=quaternions[:, k]))

    def load_point(self, data: mujoco.MjData, load_mass: float, density: float) -> tuple[np.ndarray, float]:
        """Centre (m) and radius (m) of a sphere with the volume of the load, at the payload body's COM."""
        pos = data.xipos[self.payload] if self.payload is not None else data.xpos[self.body_ids[0]]
        volume = max(load_mass, 0.0) / density if density > 0 else 0.0
        return pos.copy(), (3.0 * volume / (4.0 * math.pi)) ** (1.0 / 3.0)


def log_pile(rec: rr.RecordingStream, pile: Any) -> None:
    """The pile surface h(x) as two line strips, at both sides of the dug strip (``pile.x``, ``pile.h``, m)."""
    x, h, half = np.asarray(pile.x), np.asarray(pile.h), 0.5 * float(pile.width)
    strips = np.stack([np.column_stack((x, np.full_like(x, y), h)) for y in (-half, half)])  # one array: fast path
    rec.log(PILE_PATH, rr.LineStrips3D(strips, colors=_PILE_COLORS))


def send_load(rec: rr.RecordingStream, indexes: list[rr.TimeColumn], centres: np.ndarray, radii: np.ndarray,
              masses: np.ndarray) -> None:
    """The bucket load per step: a sphere of the load's volume at its centre, labelled with its mass (kg)."""
    labels = [f"{m:.3g} kg" for m in masses]
    rec.send_columns(LOAD_PATH, indexes=indexes, columns=rr.Points3D.columns(
        positions=centres, radii=np.maximum(radii, 1e-6), labels=labels, colors=[_LOAD_COLOR] * len(masses)))


def _archetype(kind: str, items: list[dict[str, Any]]) -> Any:
    quats = [rr.Quaternion(xyzw=q) for q in _xyzw(np.array([i["quat"] for i in items]))]
    colors = np.array([i["rgba"] for i in items], dtype=np.float32)
    pos = np.array([i["pos"] for i in items])
    if kind == "capsules":
        return rr.Capsules3D(lengths=[i["len"] for i in items], radii=[i["r"] for i in items], translations=pos,
                             quaternions=quats, colors=colors)
    if kind == "cylinders":
        return rr.Cylinders3D(lengths=[i["len"] for i in items], radii=[i["r"] for i in items], centers=pos,
                              quaternions=quats, colors=colors)
    if kind == "boxes":
        return rr.Boxes3D(half_sizes=[i["half"] for i in items], centers=pos, quaternions=quats, colors=colors,
                          fill_mode="solid")
    return rr.Ellipsoids3D(half_sizes=[i["half"] for i in items], centers=pos, quaternions=quats, colors=colors,
                           fill_mode="solid")
