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
from scipy.linalg.lapack import dgesv as _dgesv

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


class LinkageSystem:
    """The Newton–Euler system of a fixed topology, assembled with precomputed index arrays (fast per step)."""

    def __init__(self, body_names: Sequence[str], pins: Sequence[tuple[str, str | None, str]],
                 slides: Sequence[tuple[str, str, str]]) -> None:
        """``pins``: (name, parent or None, child); ``slides``: (name, barrel, rod)."""
        index = {n: i for i, n in enumerate(body_names)}
        self.n_bodies, self.pin_names, self.slide_names = len(body_names), [p[0] for p in pins], [s[0] for s in slides]
        self.n_unknown = 2 * len(pins) + 3 * len(slides)
        # each pin acts +F on its child and -F on its parent (if any); each slide +on rod, -on barrel
        self._pin_body = np.array([index[c] for _, _, c in pins] + [index[p] for _, p, _ in pins if p is not None])
        self._pin_col = np.array([2 * k for k in range(len(pins))]
                                 + [2 * k for k, (_, p, _) in enumerate(pins) if p is not None])
        self._pin_sign = np.array([1.0] * len(pins) + [-1.0] * sum(p is not None for _, p, _ in pins))
        self._pin_of = np.concatenate([np.arange(len(pins)), [k for k, (_, p, _) in enumerate(pins) if p is not None]])
        base = 2 * len(pins)
        self._sl_body = np.array([index[r] for _, _, r in slides] + [index[b] for _, b, _ in slides])
        self._sl_col = np.tile(base + 3 * np.arange(len(slides)), 2)
        self._sl_sign = np.repeat([1.0, -1.0], len(slides))
        self._sl_of = np.tile(np.arange(len(slides)), 2)

        # position-independent entries (unit force rows of the pins) are assembled once
        self._template = np.zeros((3 * self.n_bodies, self.n_unknown))
        rows, cols = 3 * self._pin_body, self._pin_col
        np.add.at(self._template, (rows, cols), self._pin_sign)
        np.add.at(self._template, (rows + 1, cols + 1), self._pin_sign)
        np.add.at(self._template, (3 * self._sl_body + 2, self._sl_col + 2), self._sl_sign)
        self._entries()

    def _entries(self) -> None:
        """Flat indices into the system matrix of its position-dependent entries, in the order :meth:`assemble` and
        :meth:`solve_floats` compute them: per pin end (child, then parent) the moment row's x and z columns; per
        slide end (rod, then barrel) and direction (axis, normal) the x, z and moment rows."""
        nu = self.n_unknown
        b, col = self._pin_body, self._pin_col
        pin = np.stack([(3 * b + 2) * nu + col, (3 * b + 2) * nu + col + 1], axis=1)
        b, col = self._sl_body, self._sl_col
        rows = np.stack([3 * b, 3 * b + 1, 3 * b + 2], axis=1)  # (slide ends, 3)
        cols = np.stack([col, col + 1], axis=1)  # (slide ends, 2): axial, transverse
        slide = rows[:, None, :] * nu + cols[:, :, None]  # (slide ends, direction, row)
        self._flat = np.concatenate([pin.ravel(), slide.ravel()])
        self._pin_sign2 = np.stack([-self._pin_sign, self._pin_sign], axis=1)  # multiplies (r_z, r_x)
        # (body, pin or slide, sign) per pin end and per slide end, in the order of ``_flat``, for solve_floats
        self._pin_terms = tuple(zip(self._pin_body.tolist(), self._pin_of.tolist(), self._pin_sign.tolist(),
                                    strict=True))
        self._slide_terms = tuple(zip(self._sl_body.tolist(), self._sl_of.tolist(), self._sl_sign.tolist(),
                                      strict=True))

    def assemble(self, mass: np.ndarray, com: np.ndarray, inertia: np.ndarray, acc: np.ndarray, alpha: np.ndarray,
                 force: np.ndarray, moment: np.ndarray, pin_points: np.ndarray, slide_points: np.ndarray,
                 slide_axes: np.ndarray, gravity: float = GRAVITY) -> tuple[np.ndarray, np.ndarray]:
        """The system matrix and right-hand side (arguments as :meth:`solve`): the template plus the
        position-dependent entries, written with one indexed assignment."""
        a = self._template.copy()
        rhs = np.empty(3 * self.n_bodies)
        rhs[0::3] = mass * acc[:, 0] - force[:, 0]
        rhs[1::3] = mass * acc[:, 1] - (force[:, 1] - mass * gravity)
        rhs[2::3] = inertia * alpha - moment
        # pins: moment of a unit force in x (−r_z) and in z (+r_x) about each body's COM, times the pin's sign
        r = pin_points[self._pin_of] - com[self._pin_body]
        pin = r[:, ::-1] * self._pin_sign2
        # slides: unit axial and transverse force (x, z) and their moment r × d about the COM, times the sign
        axis = slide_axes[self._sl_of]
        d = np.stack([axis, np.stack([-axis[:, 1], axis[:, 0]], axis=1)], axis=1)  # (slide ends, direction, xz)
        r = (slide_points[self._sl_of] - com[self._sl_body])[:, None, :]
        turn = r[..., 0] * d[..., 1] - r[..., 1] * d[..., 0]
        slide = np.concatenate([d, turn[..., None]], axis=2) * self._sl_sign[:, None, None]
        a.flat[self._flat] = np.concatenate([pin.ravel(), slide.ravel()])  # each entry unique and zero in template
        return a, rhs

    def solve_floats(self, bodies: Sequence[Sequence[float]], pin_points: Sequence[Sequence[float]],
                     slide_points: Sequence[Sequence[float]], slide_axes: Sequence[Sequence[float]],
                     gravity: float = GRAVITY) -> list[float]:
        """:meth:`solve` on Python floats, for a caller that solves every simulation step: per body (in the order
        given at construction) mass (kg), COM x, z (m), kinematic acceleration x, z (m/s²), angular acceleration
        (rad/s²), inertia about the COM (kg·m²), applied force x, z at the COM (N) and moment (N·m); per pin its
        point (x, z); per slide its point and unit axis. Returns the unknowns: per pin the x and z force on its
        child (N), then per slide the axial force, the transverse force (N) and the bending moment (N·m).

        The same equations as :meth:`assemble`, built in plain Python (numpy's per-call overhead on arrays of
        a few elements is larger than the arithmetic) and written into the matrix with one indexed assignment."""
        rhs = []
        for m, _, _, ax, az, alpha, inertia, fx, fz, moment in bodies:
            rhs += (m * ax - fx, m * az - (fz - m * gravity), inertia * alpha - moment)
        values = []
        for b, k, sign in self._pin_terms:  # unit force in x (moment −r_z) and in z (moment +r_x) at each pin end
            body = bodies[b]
            values += (-sign * (pin_points[k][1] - body[2]), sign * (pin_points[k][0] - body[1]))
        for b, k, sign in self._slide_terms:
            body = bodies[b]
            rx, rz = slide_points[k][0] - body[1], slide_points[k][1] - body[2]
            ax, az = slide_axes[k]
            for dx, dz in ((ax, az), (-az, ax)):  # axial, then transverse
                values += (sign * dx, sign * dz, sign * (rx * dz - rz * dx))
        a = self._template.copy()
        a.flat[self._flat] = values  # each entry unique and zero in the template
        return _solve(a, np.array(rhs)).tolist()

    def solve(self, mass: np.ndarray, com: np.ndarray, inertia: np.ndarray, acc: np.ndarray, alpha: np.ndarray,
              force: np.ndarray, moment: np.ndarray, pin_points: np.ndarray, slide_points: np.ndarray,
              slide_axes: np.ndarray, gravity: float = GRAVITY) -> JointForces:
        """Arrays per body (mass (n,), com (n,2), inertia (n,), acc (n,2), alpha (n,), applied force (n,2) acting at
        the COM and moment (n,)), per pin (points (p,2)), per slide (points, unit axes (s,2))."""
        a, rhs = self.assemble(mass, com, inertia, acc, alpha, force, moment, pin_points, slide_points, slide_axes,
                               gravity)
        x = _solve(a, rhs)
        residual = float(np.linalg.norm(a @ x - rhs))
        pins = {name: x[2 * k: 2 * k + 2] for k, name in enumerate(self.pin_names)}
        base = 2 * len(self.pin_names)
        axial = {name: float(x[base + 3 * k]) for k, name in enumerate(self.slide_names)}
        return JointForces(pins, axial, residual)


def _solve(a: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """``a x = rhs`` by LAPACK's ``dgesv`` (LU with partial pivoting, what ``np.linalg.solve`` calls, without its
    checks and wrapping: a few microseconds less per call); least squares if ``a`` is singular (a locked pose)."""
    _, _, x, info = _dgesv(a, rhs)  # overwrite_a and overwrite_b are off: ``a`` and ``rhs`` are left intact
    if info != 0:
        return np.linalg.lstsq(a, rhs, rcond=None)[0]
    return x


def solve_joint_forces(bodies: Sequence[PlanarBody], pins: Sequence[Pin], slides: Sequence[Slide],
                       gravity: float = GRAVITY) -> JointForces:
    """Solve the Newton–Euler system for all joint forces, bodies given as :class:`PlanarBody` objects."""
    system = LinkageSystem([b.name for b in bodies], [(p.name, p.parent, p.child) for p in pins],
                           [(s.name, s.barrel, s.rod) for s in slides])
    force = np.zeros((len(bodies), 2))
    moment = np.zeros(len(bodies))
    for i, b in enumerate(bodies):
        moment[i] = b.moment
        for point, f in b.loads:
            force[i] += f
            moment[i] += cross2(np.asarray(point) - b.com, f)
    return system.solve(
        np.array([b.mass for b in bodies]), np.array([b.com for b in bodies]), np.array([b.inertia for b in bodies]),
        np.array([b.acc for b in bodies], dtype=float), np.array([b.alpha for b in bodies]), force, moment,
        np.array([p.point for p in pins]), np.array([s.point for s in slides]), np.array([s.axis for s in slides]),
        gravity)
