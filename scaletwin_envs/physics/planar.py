"""Small planar (x–z) geometry helpers. Angles are counter-clockwise in the x–z plane (x forward, z up)."""

from __future__ import annotations

import numpy as np

Vec2 = np.ndarray


def rot(angle: float) -> np.ndarray:
    """2×2 rotation by ``angle`` (rad), counter-clockwise from +x towards +z."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


def rotate_about(point: Vec2, centre: Vec2, angle: float) -> Vec2:
    return centre + rot(angle) @ (np.asarray(point, float) - centre)


def heading(v: Vec2) -> float:
    """Angle of vector ``v`` from +x, rad."""
    return float(np.arctan2(v[1], v[0]))


def cross2(a: Vec2, b: Vec2) -> float:
    """z-less planar cross product a_x b_z − a_z b_x (the moment of b at lever a, CCW positive)."""
    return float(a[0] * b[1] - a[1] * b[0])


def circle_intersection(c1: Vec2, r1: float, c2: Vec2, r2: float, side: float) -> Vec2 | None:
    """The intersection of two circles on the given side of the line c1→c2 (sign of the cross product).

    Returns ``None`` when the circles do not meet (the linkage cannot reach that pose).
    """
    d_vec = np.asarray(c2, float) - c1
    d = float(np.hypot(*d_vec))
    if d < 1e-12 or d > r1 + r2 or d < abs(r1 - r2):
        return None
    a = (r1 * r1 - r2 * r2 + d * d) / (2 * d)
    h = np.sqrt(max(r1 * r1 - a * a, 0.0))
    u = d_vec / d
    n = np.array([-u[1], u[0]])
    return c1 + a * u + np.sign(side or 1.0) * h * n
