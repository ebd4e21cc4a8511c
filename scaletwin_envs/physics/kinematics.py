"""Planar position kinematics of the Z-bar linkage, independent of any simulator.

The configuration is two angles relative to the reference pose (rad, counter-clockwise in x–z): ``boom``
(positive raises the boom) and ``bucket`` (bucket relative to the boom; positive curls the bucket back).
Everything else (bell crank, link B, cylinder angles and lengths) follows by closing the loops with circle
intersections. The inverse problem, from cylinder lengths to angles, closes the same loops the other way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scaletwin_envs.physics.planar import circle_intersection, cross2, heading, rotate_about
from scaletwin_envs.specs.loader import LinkageGeometry


class LinkageUnreachable(ValueError):
    """The requested pose cannot be assembled (a loop does not close)."""


@dataclass(frozen=True)
class LinkagePose:
    """Every pin position (m, machine frame) and every joint angle of one assembled pose."""

    boom: float  # rad, relative to reference
    bucket: float  # rad, bucket relative to boom
    bell_crank: float  # rad, relative to boom
    link_b: float  # rad, relative to bell crank
    lift_angle: float  # rad, lift cylinder heading change
    tilt_angle: float  # rad
    lift_length: float  # m, pin to pin
    tilt_length: float  # m
    points: dict[str, np.ndarray]

    @property
    def bucket_pitch(self) -> float:
        """Absolute rotation of the bucket from the reference pose, rad."""
        return self.boom + self.bucket


def _p(v: tuple[float, float]) -> np.ndarray:
    return np.asarray(v, dtype=float)


def solve_pose(g: LinkageGeometry, boom: float, bucket: float) -> LinkagePose:
    """Assemble the linkage at boom and bucket angles (rad, relative to the reference pose)."""
    piv = _p(g.boom_pivot)
    pts: dict[str, np.ndarray] = {"boom_pivot": piv}
    for name in ("pin_O", "bell_crank_pivot", "lift_boom_pin"):
        pts[name] = rotate_about(_p(getattr(g, name)), piv, boom)
    o_ref, o = _p(g.pin_O), pts["pin_O"]
    for name in ("pin_21", "bucket_heel", "bucket_edge", "bucket_back_top"):
        pts[name] = o + rotate_about(_p(getattr(g, name)), o_ref, boom + bucket) - o_ref
    c_ref, c = _p(g.bell_crank_pivot), pts["bell_crank_pivot"]
    bottom_ref, p21_ref = _p(g.bell_crank_bottom), _p(g.pin_21)
    side = cross2(p21_ref - c_ref, bottom_ref - c_ref)
    bottom = circle_intersection(c, float(np.linalg.norm(bottom_ref - c_ref)), pts["pin_21"],
                                 float(np.linalg.norm(p21_ref - bottom_ref)), side)
    if bottom is None:
        raise LinkageUnreachable(f"link B cannot close at boom={boom:.3f} rad, bucket={bucket:.3f} rad")
    pts["bell_crank_bottom"] = bottom
    crank = heading(bottom - c) - heading(bottom_ref - c_ref) - boom
    pts["bell_crank_top"] = c + rotate_about(_p(g.bell_crank_top), c_ref, boom + crank) - c_ref
    link_b = (heading(pts["pin_21"] - bottom) - heading(p21_ref - bottom_ref)) - (boom + crank)
    lift_vec, lift_ref = pts["lift_boom_pin"] - _p(g.lift_frame_pin), _p(g.lift_boom_pin) - _p(g.lift_frame_pin)
    tilt_vec, tilt_ref = pts["bell_crank_top"] - _p(g.tilt_frame_pin), _p(g.bell_crank_top) - _p(g.tilt_frame_pin)
    pts["lift_frame_pin"], pts["tilt_frame_pin"] = _p(g.lift_frame_pin), _p(g.tilt_frame_pin)
    return LinkagePose(
        boom=boom, bucket=bucket, bell_crank=crank, link_b=link_b,
        lift_angle=heading(lift_vec) - heading(lift_ref), tilt_angle=heading(tilt_vec) - heading(tilt_ref),
        lift_length=float(np.linalg.norm(lift_vec)), tilt_length=float(np.linalg.norm(tilt_vec)), points=pts,
    )


def boom_angle_for_lift_length(g: LinkageGeometry, lift_length: float) -> float:
    """Boom angle (rad) at which the lift cylinder measures ``lift_length`` (m) pin to pin."""
    piv, ref = _p(g.boom_pivot), _p(g.lift_boom_pin)
    frame_pin = _p(g.lift_frame_pin)
    side = cross2(frame_pin - piv, ref - piv)
    pin = circle_intersection(piv, float(np.linalg.norm(ref - piv)), frame_pin, lift_length, side)
    if pin is None:
        raise LinkageUnreachable(f"lift cylinder length {lift_length:.4f} m cannot be assembled")
    return _wrap(heading(pin - piv) - heading(ref - piv))


def bucket_angle_for_tilt_length(g: LinkageGeometry, boom: float, tilt_length: float) -> float:
    """Bucket angle relative to the boom (rad) at which the tilt cylinder measures ``tilt_length`` (m)."""
    c_ref, top_ref, bottom_ref = _p(g.bell_crank_pivot), _p(g.bell_crank_top), _p(g.bell_crank_bottom)
    piv, frame_pin = _p(g.boom_pivot), _p(g.tilt_frame_pin)
    c = rotate_about(c_ref, piv, boom)
    side = cross2(frame_pin - c_ref, top_ref - c_ref)
    top = circle_intersection(c, float(np.linalg.norm(top_ref - c_ref)), frame_pin, tilt_length, side)
    if top is None:
        raise LinkageUnreachable(f"tilt cylinder length {tilt_length:.4f} m cannot be assembled")
    crank = heading(top - c) - heading(top_ref - c_ref) - boom
    bottom = c + rotate_about(bottom_ref, c_ref, boom + crank) - c_ref
    o_ref, p21_ref = _p(g.pin_O), _p(g.pin_21)
    o = rotate_about(o_ref, piv, boom)
    side = cross2(bottom_ref - o_ref, p21_ref - o_ref)
    p21 = circle_intersection(o, float(np.linalg.norm(p21_ref - o_ref)), bottom,
                              float(np.linalg.norm(p21_ref - bottom_ref)), side)
    if p21 is None:
        raise LinkageUnreachable(f"link B cannot close at tilt length {tilt_length:.4f} m")
    return _wrap(heading(p21 - o) - heading(p21_ref - o_ref) - boom)


def pose_from_cylinders(g: LinkageGeometry, lift_length: float, tilt_length: float) -> LinkagePose:
    """The assembled pose for given cylinder pin-to-pin lengths (m)."""
    boom = boom_angle_for_lift_length(g, lift_length)
    return solve_pose(g, boom, bucket_angle_for_tilt_length(g, boom, tilt_length))


def _wrap(a: float) -> float:
    return float((a + np.pi) % (2 * np.pi) - np.pi)


def tilt_ratio(g: LinkageGeometry, boom: float, pitch: float) -> float:
    """Force ratio of the tilt linkage, F21 / tilt-cylinder force, with massless bell crank and link B (1).

    Link B is a two-force member, so F21 acts along it; the bell crank's moment balance about its pivot then gives
    ``F21 · r_B = F_tilt · r_tilt`` with ``r`` the perpendicular distance of the pivot from each force's line. The
    ratio depends on the design and the pose only (boom angle and absolute bucket pitch, rad), which is why the
    machine's geometry and pose carry what Eq. (10)'s groups cannot: how a cylinder force reaches the pin.

    Raises:
        LinkageUnreachable: the pose cannot be assembled.
    """
    pts = solve_pose(g, boom, pitch - boom).points
    c = pts["bell_crank_pivot"]
    u_tilt = pts["bell_crank_top"] - pts["tilt_frame_pin"]
    u_b = pts["pin_21"] - pts["bell_crank_bottom"]
    r_tilt = abs(cross2(pts["bell_crank_top"] - c, u_tilt / np.linalg.norm(u_tilt)))
    r_b = abs(cross2(pts["bell_crank_bottom"] - c, u_b / np.linalg.norm(u_b)))
    return float(r_tilt / r_b) if r_b > 0 else float("inf")


#: Closest approach (rad) of link B to a dead centre with the bucket's lever (pin 21 → O) that the bucket stops
#: allow (:func:`bucket_stops`). A design rule of ours, no published band: mechanism texts keep a transmission
#: angle well away from 0 and 180° wherever a linkage must carry load; 10° leaves every pose the ER12's scripted
#: dig and the paper's recordings reach (they come no closer than 14°) and stops the machines of the product
#: line whose tilt stroke reaches past the dead centre at a raised boom (without it their simulated Z-bar
#: snapped through to its other assembly branch under a rack-back at relief, or when the lowered boom pressed the
#: bucket into the ground and curled it back).
BUCKET_STOP_MARGIN = math.radians(10.0)


def link_b_transmission(pose: LinkagePose) -> float:
    """Interior angle at pin 21 between link B (towards the bell crank's bottom pin) and the bucket's lever
    (towards O), rad in [0, π]; 0 (folded) and π (stretched) are the dead centres where the tilt linkage holds no
    bucket moment."""
    p = pose.points
    u, v = p["bell_crank_bottom"] - p["pin_21"], p["pin_O"] - p["pin_21"]
    return float(math.atan2(abs(cross2(u, v)), float(np.dot(u, v))))


def bucket_stops(g: LinkageGeometry, margin: float = BUCKET_STOP_MARGIN) -> tuple[float, float]:
    """The bucket's stops on the boom (a real Z-bar's rack-back and dump stops): the bucket angles relative to the
    boom (rad, 0 in the reference pose; the range of the joint ``bucket_hinge``), lower first, at which link B
    comes within ``margin`` rad of a dead centre with the bucket's lever (:func:`link_b_transmission` leaves
    [margin, π − margin]) on either side of the reference pose. ±π on a side where the bucket's travel ends
    first (the bell crank and link B in line: the linkage's own limit) or no dead centre lies.

    The bell crank turns about its pivot on the boom, so the distance from O to the bell crank's bottom pin, and
    with it that angle (law of cosines in the triangle O, pin 21, bottom pin), depends on the bell crank's angle
    alone: the crank angles where it leaves the band are found first, then the bucket angles they give. A stop on
    the bucket rather than on the bell crank also carries what the ground does to the bucket (a boom lowered onto
    it) without loading the linkage.

    Raises:
        ValueError: the reference pose itself lies within ``margin`` of a dead centre, or ``margin`` is not in
            [0, π/2).
    """
    if not 0.0 <= margin < 0.5 * math.pi:
        raise ValueError(f"margin must be in [0, π/2) rad, got {margin}")
    c, bottom, o, p21 = (_p(v) for v in (g.bell_crank_pivot, g.bell_crank_bottom, g.pin_O, g.pin_21))
    a, b = float(np.linalg.norm(p21 - o)), float(np.linalg.norm(p21 - bottom))
    # the transmission angle leaves [margin, π − margin] where |O − bottom| leaves [d_lo, d_hi]
    d_lo = math.sqrt(a * a + b * b - 2.0 * a * b * math.cos(margin))
    d_hi = math.sqrt(a * a + b * b + 2.0 * a * b * math.cos(margin))

    def inside(phi: float) -> bool:
        d = float(np.linalg.norm(rotate_about(bottom, c, phi) - o))
        return d_lo <= d <= d_hi

    if not inside(0.0):
        raise ValueError(f"the reference pose lies within {math.degrees(margin):.1f}° of link B's dead centre")
    side = cross2(bottom - o, p21 - o)

    def bucket(phi: float) -> float:
        pin = circle_intersection(o, a, rotate_about(bottom, c, phi), b, side)
        if pin is None:  # cannot happen inside the band (the dead centres lie outside it)
            raise LinkageUnreachable(f"link B cannot close at bell-crank angle {phi:.4f} rad")
        return _wrap(heading(pin - o) - heading(p21 - o))

    stops = []
    for sign in (-1.0, 1.0):
        step, phi, turn = 1e-2, 0.0, bucket(sign * 1e-2)
        here = bucket(0.0)
        while phi < math.pi and inside(sign * (phi + step)):
            ahead = bucket(sign * (phi + step))
            if (ahead - here) * turn < 0.0:
                break  # the bucket turns back: crank and link B in line, the linkage's own limit on this side
            phi, here = phi + step, ahead
        else:
            if phi < math.pi:  # the band's edge: bisect the crossing to 1e-9 rad
                lo, hi = phi, phi + step
                while hi - lo > 1e-9:
                    mid = 0.5 * (lo + hi)
                    lo, hi = (mid, hi) if inside(sign * mid) else (lo, mid)
                stops.append(bucket(sign * lo))
                continue
        stops.append(math.copysign(math.pi, turn))  # no dead centre of link B with the lever on this side
    return min(stops), max(stops)
