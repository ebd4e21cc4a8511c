"""Analytical statics of the loader linkage at any pose and load, independent of MuJoCo.

Used as the reference the simulator is checked against (pin forces at rest) and to generate the
miniature-validation data of the paper's section 4 (static equilibrium under known loads).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from scaletwin_envs.physics.bucket import load_centroid
from scaletwin_envs.physics.kinematics import LinkagePose, pose_from_cylinders, solve_pose
from scaletwin_envs.physics.mass_layout import BodyLayout, cylinder_axis, linkage_layout
from scaletwin_envs.physics.newton_euler import JointForces, Pin, PlanarBody, Slide, solve_joint_forces
from scaletwin_envs.physics.planar import rot
from scaletwin_envs.specs.loader import LoaderSpec

#: (pin name, parent body or None for the frame, child body, point name in the pose).
LINKAGE_PINS: tuple[tuple[str, str | None, str, str], ...] = (
    ("boom_pivot", None, "boom", "boom_pivot"),
    ("O", "boom", "bucket", "pin_O"),
    ("bell_crank_pivot", "boom", "bell_crank", "bell_crank_pivot"),
    ("bell_crank_bottom", "bell_crank", "link_b", "bell_crank_bottom"),
    ("pin_21", "link_b", "bucket", "pin_21"),
    ("lift_frame", None, "lift_barrel", "lift_frame_pin"),
    ("lift_boom", "lift_rod", "boom", "lift_boom_pin"),
    ("tilt_frame", None, "tilt_barrel", "tilt_frame_pin"),
    ("tilt_crank", "tilt_rod", "bell_crank", "bell_crank_top"),
)
CYLINDERS = (("lift", "lift_frame_pin", "lift_boom_pin"), ("tilt", "tilt_frame_pin", "bell_crank_top"))


def linkage_joints(points: Mapping[str, np.ndarray]) -> tuple[list[Pin], list[Slide]]:
    """Pins and cylinder slides of the Z-bar loader at the given pin positions (m)."""
    pins = [Pin(name, parent, child, np.asarray(points[p], float)) for name, parent, child, p in LINKAGE_PINS]
    slides = []
    for name, start, end in CYLINDERS:
        a, b = np.asarray(points[start], float), np.asarray(points[end], float)
        axis = (b - a) / np.linalg.norm(b - a)
        slides.append(Slide(name, f"{name}_barrel", f"{name}_rod", 0.5 * (a + b), axis))
    return pins, slides


def combine(a: PlanarBody, b: PlanarBody) -> PlanarBody:
    """Rigidly merge body ``b`` into ``a`` (parallel-axis theorem); the COM acceleration is mass-weighted and the
    angular acceleration is ``a``'s (they move as one)."""
    if b.mass <= 0.0:
        return a
    total = a.mass + b.mass
    c = (a.mass * a.com + b.mass * b.com) / total
    i = a.inertia + a.mass * float(np.sum((a.com - c) ** 2)) + b.inertia + b.mass * float(np.sum((b.com - c) ** 2))
    acc = (a.mass * np.asarray(a.acc) + b.mass * np.asarray(b.acc)) / total
    return PlanarBody(a.name, total, c, i, acc, a.alpha, [*a.loads, *b.loads], a.moment + b.moment)


@dataclass(frozen=True)
class StaticSolution:
    """Pin forces at rest: ``F21``/``F31`` magnitudes and vectors (N, on the bucket), cylinder forces (N)."""

    pose: LinkagePose
    forces: JointForces
    payload_mass: float

    @property
    def F21_vec(self) -> np.ndarray:
        return self.forces.pins["pin_21"]

    @property
    def F31_vec(self) -> np.ndarray:
        return self.forces.pins["O"]

    @property
    def F21(self) -> float:
        return float(np.linalg.norm(self.F21_vec))

    @property
    def F31(self) -> float:
        return float(np.linalg.norm(self.F31_vec))

    @property
    def Pf_lift(self) -> float:
        return self.forces.axial["lift"]

    @property
    def Pf_tilt(self) -> float:
        return self.forces.axial["tilt"]


def place_bodies(spec: LoaderSpec, pose: LinkagePose, layout: Mapping[str, BodyLayout] | None = None
                 ) -> dict[str, PlanarBody]:
    """World COMs and inertias of the linkage bodies at a pose (at rest)."""
    layout = layout or linkage_layout(spec)
    pts = pose.points
    placements = {
        "boom": (pts["boom_pivot"], pose.boom),
        "bucket": (pts["pin_O"], pose.boom + pose.bucket),
        "bell_crank": (pts["bell_crank_pivot"], pose.boom + pose.bell_crank),
        "link_b": (pts["bell_crank_bottom"], pose.boom + pose.bell_crank + pose.link_b),
    }
    for name, start, _ in CYLINDERS:
        ref_axis, ref_len = cylinder_axis(spec, name)
        angle, length = (pose.lift_angle, pose.lift_length) if name == "lift" else (pose.tilt_angle, pose.tilt_length)
        placements[f"{name}_barrel"] = (pts[start], angle)
        placements[f"{name}_rod"] = (pts[start] + rot(angle) @ ref_axis * (length - ref_len), angle)
    bodies = {}
    for name, (origin, angle) in placements.items():
        lay = layout[name]
        bodies[name] = PlanarBody(name, lay.mass, origin + rot(angle) @ lay.com, lay.inertia)
    return bodies


def solve_static(spec: LoaderSpec, pose: LinkagePose, payload_mass: float = 0.0,
                 payload_com_local: np.ndarray | None = None,
                 bucket_loads: Sequence[tuple[np.ndarray, np.ndarray]] = ()) -> StaticSolution:
    """Static equilibrium at ``pose`` with a payload in the bucket and extra forces on the bucket.

    Args:
        payload_mass: kg, rigidly carried by the bucket.
        payload_com_local: payload COM relative to O in the bucket's reference orientation (m); by default
            the centroid of a bucket filled to the payload's volume of gravel-like material.
        bucket_loads: (point, force) pairs in the machine frame (m, N), e.g. a breakout test force.
    """
    bodies = place_bodies(spec, pose)
    if payload_mass > 0.0:
        if payload_com_local is None:
            fill = min(payload_mass / max(spec.rated_load, 1e-12), 1.0)
            payload_com_local = load_centroid(spec.geometry, fill) - np.asarray(spec.geometry.pin_O)
        com = pose.points["pin_O"] + rot(pose.bucket_pitch) @ np.asarray(payload_com_local, float)
        bodies["bucket"] = combine(bodies["bucket"], PlanarBody("payload", payload_mass, com, 0.0))
    bodies["bucket"].loads.extend((np.asarray(p, float), np.asarray(f, float)) for p, f in bucket_loads)
    pins, slides = linkage_joints(pose.points)
    return StaticSolution(pose, solve_joint_forces(list(bodies.values()), pins, slides), payload_mass)


def static_at(spec: LoaderSpec, boom: float = 0.0, bucket: float = 0.0, **kwargs: object) -> StaticSolution:
    """:func:`solve_static` at boom / bucket angles (rad, relative to the reference pose)."""
    return solve_static(spec, solve_pose(spec.geometry, boom, bucket), **kwargs)  # type: ignore[arg-type]


def static_at_cylinders(spec: LoaderSpec, lift_length: float, tilt_length: float, **kwargs: object) -> StaticSolution:
    """:func:`solve_static` at cylinder pin-to-pin lengths (m)."""
    return solve_static(spec, pose_from_cylinders(spec.geometry, lift_length, tilt_length), **kwargs)  # type: ignore[arg-type]


def breakout_force(spec: LoaderSpec) -> float:
    """Largest upward force (N) 100 mm behind the cutting edge, edge on the ground, that the tilt cylinder can
    resist at relief pressure (SAE J732 / ISO 14397-2 style, with the bucket floor level)."""
    pose = solve_pose(spec.geometry, 0.0, 0.0)
    edge, heel = pose.points["bucket_edge"], pose.points["bucket_heel"]
    point = edge + (heel - edge) / np.linalg.norm(heel - edge) * 0.1 * spec.scale
    unit = solve_static(spec, pose, bucket_loads=[(point, np.array([0.0, 1.0]))]).Pf_tilt
    dead = solve_static(spec, pose).Pf_tilt
    # tilt force is affine in the test force: dead + unit_slope * F; the cylinder resists by retracting
    # (pulling) or extending, whichever the sign requires.
    slope = unit - dead
    limit = -spec.tilt.max_retract_force if slope < 0 else spec.tilt.max_extend_force
    return float((limit - dead) / slope)
