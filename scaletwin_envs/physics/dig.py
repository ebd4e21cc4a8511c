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
from scaletwin_envs.physics.earthmoving import bearing_pressure, blade_force, side_drag
from scaletwin_envs.physics.pile import Pile
from scaletwin_envs.specs.soil import SoilSpec

GRAVITY = 9.81
EDGE_THICKNESS = 0.012  # cutting edge thickness / boom length (a 28 mm edge on the ER12), estimate
CREEP_SPEED = 0.01  # soil resistance reaches tanh(1) of its full value at this speed / sqrt(g L), estimate


@dataclass
class DigForces:
    """Resistance on the bucket (N, machine frame x–z), its point of application and its components."""

    force: np.ndarray
    point: np.ndarray
    cutting: float = 0.0
    bearing: float = 0.0
    side: float = 0.0
    depth: float = 0.0


class DigModel:
    """Soil resistance and bucket fill for one bucket in one pile."""

    def __init__(self, soil: SoilSpec, pile: Pile, width: float, capacity: float, length_scale: float) -> None:
        self.soil, self.pile, self.width = soil, pile, width
        self.capacity = capacity  # heaped volume, m³
        self.length_scale = length_scale
        self.load_volume = 0.0  # m³ in the bucket
        self.spilled_volume = 0.0  # m³ spilled since reset
        self.creep = CREEP_SPEED * math.sqrt(GRAVITY * length_scale)

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
        if room > 0.0:
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

    def resistance(self, edge: np.ndarray, blade_top: np.ndarray, floor_back: np.ndarray,
                   edge_velocity: np.ndarray) -> DigForces:
        """Soil force on the bucket at the cutting edge for the current pose and edge velocity (m/s)."""
        ahead = edge[0] + 0.5 * self.pile.dx
        depth = self.pile.surface(ahead) - edge[1]
        side_depth = self.pile.initial_surface(edge[0]) - edge[1]
        speed = float(np.hypot(*edge_velocity))
        if (depth <= 0.0 and side_depth <= 0.0) or speed < 1e-12:
            return DigForces(np.zeros(2), edge.copy())
        travel = edge_velocity / speed
        blade = (blade_top - edge) / max(float(np.hypot(*(blade_top - edge))), 1e-12)
        rake = math.acos(float(np.clip(np.dot(blade, -travel), -1.0, 1.0)))
        along, press = blade_force(self.soil, self.width, max(depth, 0.0), rake)
        bearing = self.width * EDGE_THICKNESS * self.length_scale * bearing_pressure(self.soil, depth) if depth > 0 else 0.0
        buried = min(float(np.hypot(*(edge - floor_back))), max(side_depth, 0.0) / math.tan(self.soil.repose_angle))
        side = side_drag(self.soil, max(side_depth, 0.0), buried)
        smooth = math.tanh(speed / self.creep)
        down = np.array([travel[1], -travel[0]])
        force = smooth * (-(along + bearing + side) * travel + press * down)
        return DigForces(force, edge.copy(), along * smooth, bearing * smooth, side * smooth, max(depth, 0.0))
