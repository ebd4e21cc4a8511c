"""Planar Newton–Euler of the loader linkage: every pin and cylinder force from kinematics and loads alone.

This is the second, simulator-independent route to the pin forces. Each body contributes three equations,
``ΣF = m a`` and ``ΣM_G = I_G α``, with its weight, known applied loads and (for statics) zero acceleration.
Unknowns are the planar pin forces (two per pin) and, for each cylinder, the axial force, the transverse
force and the bending moment the barrel exerts on the rod. Bodies pinned to the machine frame take the frame
as ground, so the frame itself contributes no equations. The system is square for the Z-bar loader.

Sign conventions: x forward, z up; moments and angular accelerations counter-clockwise in x–z.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from scaletwin_envs.physics.planar import cross2

GRAVITY = 9.81


@dataclass
class PlanarBody:
    """A rigid body in the plane: mass (kg), COM (m), inertia about the COM (kg·m²), kinematic accelerations."""

    name: str
    mass: float
    com: np.ndarray
    inertia: float
    acc: np.ndarray = field(default_factory=lambda: np.zeros(2))  # m/s², kinematic (not proper)
    alpha: float = 0.0  # rad/s²
    loads: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)  # (point, force) pairs, N
    moment: float = 0.0  # applied pure moment, N·m


@dataclass(frozen=True)
class Pin:
    """A revolute joint at ``point``: unknown force of ``parent`` on ``child`` (parent ``None`` = frame)."""

    name: str
    parent: str | None
    child: str
    point: np.ndarray


@dataclass(frozen=True)
class Slide:
    """A cylinder's prismatic joint: barrel on rod along unit ``axis``, reduced to ``point`` on the axis."""

    name: str
    barrel: str
    rod: str
    point: np.ndarray
    axis: np.ndarray


@dataclass
class JointForces:
    """Solution: force on the child body of each pin (N), axial force of each slide (N, + pushes rod out)."""

    pins: dict[str, np.ndarray]
    axial: dict[str, float]
    residual: float  # norm of the equation residual, N (zero for a square, consistent system)


def solve_joint_forces(bodies: Sequence[PlanarBody], pins: Sequence[Pin], slides: Sequence[Slide],
                       gravity: float = GRAVITY) -> JointForces:
    """Solve the linear Newton–Euler system for all joint forces."""
    index = {b.name: i for i, b in enumerate(bodies)}
    n_unknown = 2 * len(pins) + 3 * len(slides)
    a = np.zeros((3 * len(bodies), n_unknown))
    rhs = np.zeros(3 * len(bodies))
    for i, b in enumerate(bodies):
        applied = np.array([0.0, -b.mass * gravity])
        moment = b.moment
        for point, force in b.loads:
            applied = applied + force
            moment += cross2(point - b.com, force)
        rhs[3 * i: 3 * i + 2] = b.mass * np.asarray(b.acc) - applied
        rhs[3 * i + 2] = b.inertia * b.alpha - moment
    col = 0
    for pin in pins:
        _add_force(a, index, bodies, pin.child, pin.point, col, +1.0)
        if pin.parent is not None:
            _add_force(a, index, bodies, pin.parent, pin.point, col, -1.0)
        col += 2
    for s in slides:
        normal = np.array([-s.axis[1], s.axis[0]])
        for body, sign in ((s.rod, 1.0), (s.barrel, -1.0)):
            i = index[body]
            r = s.point - bodies[i].com
            for k, direction in enumerate((s.axis, normal)):
                a[3 * i: 3 * i + 2, col + k] += sign * direction
                a[3 * i + 2, col + k] += sign * cross2(r, direction)
            a[3 * i + 2, col + 2] += sign
        col += 3
    x, *_ = np.linalg.lstsq(a, rhs, rcond=None)
    residual = float(np.linalg.norm(a @ x - rhs))
    out_pins = {p.name: x[2 * k: 2 * k + 2].copy() for k, p in enumerate(pins)}
    base = 2 * len(pins)
    axial = {s.name: float(x[base + 3 * k]) for k, s in enumerate(slides)}
    return JointForces(out_pins, axial, residual)


def _add_force(a: np.ndarray, index: dict[str, int], bodies: Sequence[PlanarBody], body: str,
               point: np.ndarray, col: int, sign: float) -> None:
    i = index[body]
    r = point - bodies[i].com
    a[3 * i, col] += sign
    a[3 * i + 1, col + 1] += sign
    a[3 * i + 2, col] += sign * -r[1]
    a[3 * i + 2, col + 1] += sign * r[0]
