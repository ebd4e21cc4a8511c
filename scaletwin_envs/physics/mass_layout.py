"""Where each body's mass sits: local centre of mass and planar inertia, shared by the MuJoCo builder and the
analytical statics so both routes describe the same machine.

Local coordinates are planar offsets (m) from the body's joint in the reference pose orientation. Mass
distributions are *estimates* from the outline (beams as slender rods, the bucket as plates); the masses
themselves come from the :class:`LoaderSpec`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scaletwin_envs.specs.loader import LoaderSpec

ROD_FRACTION = 0.9  # rod length / closed length of a cylinder (the rest is gland and piston), estimate
BARREL_COM_FRACTION = 0.4  # barrel COM from its pin, as a fraction of the closed length, estimate


@dataclass(frozen=True)
class BodyLayout:
    """Mass (kg), COM offset from the body's joint (m) and inertia about the COM for rotation in x–z (kg·m²)."""

    mass: float
    com: np.ndarray
    inertia: float


def _p(v: tuple[float, float]) -> np.ndarray:
    return np.asarray(v, dtype=float)


def cylinder_axis(spec: LoaderSpec, which: str) -> tuple[np.ndarray, float]:
    """Unit axis and pin-to-pin length of a cylinder in the reference pose."""
    g = spec.geometry
    start, end = (g.lift_frame_pin, g.lift_boom_pin) if which == "lift" else (g.tilt_frame_pin, g.bell_crank_top)
    vec = _p(end) - _p(start)
    length = float(np.linalg.norm(vec))
    return vec / length, length


def linkage_layout(spec: LoaderSpec) -> dict[str, BodyLayout]:
    """Layouts of boom, bucket, bell_crank, link_b and the four cylinder parts."""
    g, m = spec.geometry, spec.masses
    piv, o, c = _p(g.boom_pivot), _p(g.pin_O), _p(g.bell_crank_pivot)
    top, bottom, p21 = _p(g.bell_crank_top), _p(g.bell_crank_bottom), _p(g.pin_21)
    heel, edge, back = _p(g.bucket_heel), _p(g.bucket_edge), _p(g.bucket_back_top)
    boom_len = float(np.linalg.norm(o - piv))
    boom_com = 0.8 * 0.5 * (piv + o) + 0.2 * c
    bucket_com = (heel + 0.5 * (heel + edge) + 0.5 * (heel + back)) / 3.0
    floor, wall = float(np.linalg.norm(edge - heel)), float(np.linalg.norm(back - heel))
    crank_com = (top + c + bottom) / 3.0
    crank_arms = float(np.linalg.norm(top - c) ** 2 + np.linalg.norm(bottom - c) ** 2)
    link_len = float(np.linalg.norm(p21 - bottom))
    out = {
        "boom": BodyLayout(m.boom, boom_com - piv, m.boom * boom_len**2 / 12.0),
        "bucket": BodyLayout(m.bucket, bucket_com - o, m.bucket * (floor**2 + wall**2) / 12.0),
        "bell_crank": BodyLayout(m.bell_crank, crank_com - c, m.bell_crank * crank_arms / 6.0),
        "link_b": BodyLayout(m.link_b, 0.5 * (p21 - bottom), m.link_b * link_len**2 / 12.0),
    }
    for which, cyl in (("lift", spec.lift), ("tilt", spec.tilt)):
        axis, length = cylinder_axis(spec, which)
        rod_len = ROD_FRACTION * cyl.closed_length
        out[f"{which}_barrel"] = BodyLayout(cyl.barrel_mass, axis * BARREL_COM_FRACTION * cyl.closed_length,
                                            cyl.barrel_mass * cyl.closed_length**2 / 12.0)
        out[f"{which}_rod"] = BodyLayout(cyl.rod_mass, axis * (length - 0.5 * rod_len),
                                         cyl.rod_mass * rod_len**2 / 12.0)
    return out


def chassis_com(spec: LoaderSpec) -> np.ndarray:
    """Chassis COM in the machine frame (m): behind and below the boom pivot, estimate."""
    return np.array([-0.55, 0.5]) * spec.characteristic_length
