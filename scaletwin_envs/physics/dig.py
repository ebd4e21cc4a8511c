"""Bucket–pile interaction: resistance on the bucket and material flowing into, and spilling out of, it.

The bucket's cavity (heel, cutting edge, top of the back wall) is a triangle in the x–z plane. Pile material
inside the cavity moves into the bucket (up to the capacity held at the current pitch); what is above the
cavity slides down. Resistance acts at the cutting edge: the fundamental earthmoving equation for the
undisturbed soil ahead of the edge, edge bearing and side-plate drag, opposing the edge's velocity and
smoothed below a creep speed that scales with √(gL), so the whole model is Froude-similar in dry soil.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scaletwin_envs.physics.bucket import capacity_fraction
from scaletwin_envs.physics.earthmoving import soil_resistance
from scaletwin_envs.physics.pile import Pile
from scaletwin_envs.specs.soil import SoilSpec

GRAVITY = 9.81
EDGE_THICKNESS = 0.012  # cutting edge thickness / boom length (a 28 mm edge on the ER12), estimate
CREEP_SPEED = 0.05  # soil resistance is full above this edge speed / sqrt(g L) and linear below it, estimate


@dataclass
class DigForces:
    """Soil resistance on the bucket at the cutting edge, for travel at or above the creep speed (N).

    ``resist`` opposes the edge's travel, ``press`` pushes the blade into the soil (to the right of travel,
    i.e. downwards when moving forward). Below the creep speed both fall linearly to zero, so a stalled bucket
    is held by soil that behaves as a stiff damper rather than a discontinuous Coulomb force.
    """

    resist: float = 0.0
    press: float = 0.0
    travel: tuple[float, float] = (1.0, 0.0)
    cutting: float = 0.0
    bearing: float = 0.0
    side: float = 0.0
    depth: float = 0.0  # m below the pile surface


NO_FORCE = DigForces()


class DigModel:
    """Soil resistance and bucket fill for one bucket in one pile."""

    def __init__(self, soil: SoilSpec, pile: Pile, width: float, capacity: float, length_scale: float) -> None:
        self.soil, self.pile, self.width = soil, pile, width
        self.capacity = capacity  # heaped volume, m³
        self.length_scale = length_scale
        self.load_volume = 0.0  # m³ in the bucket
        self.spilled_volume = 0.0  # m³ spilled since reset
        self.creep = CREEP_SPEED * math.sqrt(GRAVITY * length_scale)
        self._forces = soil_resistance(soil)  # the soil's constants, worked out once
        self._edge_area = width * EDGE_THICKNESS * length_scale  # m²
        self._tan_repose = math.tan(soil.repose_angle)

    @property
    def load_mass(self) -> float:
        return self.load_volume * self.soil.density

    def fill(self) -> float:
        """Loaded volume over heaped capacity."""
        return self.load_volume / self.capacity

    def transfer(self, cavity: np.ndarray, pitch: float) -> float:
        """Move pile material inside the cavity into the bucket; spill what the pitch cannot hold. Returns m³ in."""
        held = capacity_fraction(pitch) * self.capacity
        room = max(held - self.load_volume, 0.0)
        moved = 0.0
        if room > 0.0 and self.pile.reaches(cavity):
            idx, heights = self.pile.overlap(cavity)
            available = float(heights.sum() * self.pile.dx * self.width)
            if available > 0.0:
                moved = self.pile.remove(idx, heights * min(1.0, room / available))
                self.load_volume += moved
        if self.load_volume > held:
            spill = self.load_volume - held
            self.load_volume = held
            self.spilled_volume += spill
            edge_x = float(cavity[1, 0])
            self.pile.deposit(edge_x, spill, spread=0.3 * self.length_scale)
        return moved

    def resistance(self, edge: tuple[float, float], blade_top: tuple[float, float], floor_back: tuple[float, float],
                   edge_velocity: tuple[float, float]) -> DigForces:
        """Soil force on the bucket at the cutting edge for the current pose and edge velocity (m, m/s).

        Runs several times per control step, so it sticks to scalar arithmetic (and conditional expressions
        for ``min``/``max``, which cost ten times as much as calls; same operands, so the same values).
        """
        ex, ez = edge
        depth = self.pile.surface(ex + 0.5 * self.pile.dx) - ez
        side_depth = self.pile.initial_surface(ex) - ez
        vx, vz = edge_velocity
        speed = math.hypot(vx, vz)
        if (depth <= 0.0 and side_depth <= 0.0) or speed < 1e-12:
            return NO_FORCE
        tx, tz = vx / speed, vz / speed
        bx, bz = blade_top[0] - ex, blade_top[1] - ez
        blen = math.hypot(bx, bz) or 1e-12
        c = -(bx * tx + bz * tz) / blen
        c = c if c < 1.0 else 1.0
        rake = math.acos(c if c > -1.0 else -1.0)
        depth = 0.0 if depth < 0.0 else depth
        forces = self._forces
        along, press = forces.blade(self.width, depth, rake)
        bearing = self._edge_area * forces.bearing(depth) if depth > 0 else 0.0
        side_depth = 0.0 if side_depth < 0.0 else side_depth
        floor, reach = math.hypot(ex - floor_back[0], ez - floor_back[1]), side_depth / self._tan_repose
        buried = reach if reach < floor else floor
        side = forces.side(side_depth, buried)
        return DigForces(along + bearing + side, press, (tx, tz), along, bearing, side, depth)
