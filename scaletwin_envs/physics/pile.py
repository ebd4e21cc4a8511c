"""The soil pile: a planar height profile along x on a strip as wide as the bucket, consumed as it is dug."""

from __future__ import annotations

import math

import numpy as np


class Pile:
    """Height field ``h(x)`` (m) on a uniform grid; volumes are per the strip ``width`` (m).

    The pile rises from its toe at ``toe_x`` at the repose angle to a flat top of ``height``. ``initial`` keeps
    the undisturbed profile, whose material beside the dug strip still drags on the bucket's side plates.
    """

    def __init__(self, toe_x: float, height: float, repose: float, length: float, width: float,
                 cells: int = 240) -> None:
        if height <= 0 or length <= 0 or width <= 0:
            raise ValueError("pile height, length and width must be > 0")
        self.x = np.linspace(toe_x, toe_x + length, cells)
        self.dx = float(self.x[1] - self.x[0])
        self.width = width
        self.h = np.minimum(height, (self.x - toe_x) * math.tan(repose)).clip(min=0.0)
        self.initial = self.h.copy()
        self._x0, self._last = float(self.x[0]), cells - 1
        self._top = float(self.h.max())  # the pile never grows higher than this except where spill lands

    def surface(self, x: float) -> float:
        """Current height at x (0 outside the pile), m."""
        return self._interp(self.h, x)

    def initial_surface(self, x: float) -> float:
        """Undisturbed height at x, m."""
        return self._interp(self.initial, x)

    def _interp(self, h: np.ndarray, x: float) -> float:
        u = (x - self._x0) / self.dx
        if u < 0.0 or u > self._last:
            return 0.0
        k = min(int(u), self._last - 1)
        t = u - k
        return float(h[k] * (1.0 - t) + h[k + 1] * t)

    @property
    def volume(self) -> float:
        """Material left in the strip, m³."""
        return float(self.h.sum() * self.dx * self.width)

    def reaches(self, polygon: np.ndarray) -> bool:
        """Cheap test: could the polygon (N×2, x–z) hold any pile material?"""
        return bool(polygon[:, 0].max() >= self._x0 and polygon[:, 1].min() < self._top)

    def overlap(self, polygon: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cell indices and heights (m) of pile material lying inside a convex polygon (N×2, x–z)."""
        lo, hi = polygon[:, 0].min(), polygon[:, 0].max()
        first = max(int(np.ceil((lo - self._x0) / self.dx)), 0)
        last = min(int(np.floor((hi - self._x0) / self.dx)), self._last)
        idx = np.arange(first, last + 1)
        if idx.size == 0:
            return idx, np.zeros(0)
        xs = self.x[idx]
        z_lo = np.full(idx.size, np.inf)
        z_hi = np.full(idx.size, -np.inf)
        for k in range(len(polygon)):  # a vertical line meets a convex polygon's edges at its bottom and top
            (x0, z0), (x1, z1) = polygon[k], polygon[(k + 1) % len(polygon)]
            if abs(x1 - x0) < 1e-12:
                continue
            t = (xs - x0) / (x1 - x0)
            z = np.where((t >= 0.0) & (t <= 1.0), z0 + t * (z1 - z0), np.nan)
            z_lo = np.fmin(z_lo, z)
            z_hi = np.fmax(z_hi, z)
        inside = np.isfinite(z_lo) & np.isfinite(z_hi)
        depth = np.where(inside, np.minimum(self.h[idx], z_hi) - np.where(inside, z_lo, 0.0), 0.0).clip(min=0.0)
        return idx, depth

    def remove(self, idx: np.ndarray, heights: np.ndarray) -> float:
        """Take material from columns (the material above slides down); returns the volume removed, m³."""
        self.h[idx] = (self.h[idx] - heights).clip(min=0.0)
        return float(heights.sum() * self.dx * self.width)

    def reshaped(self) -> None:
        """Tell the pile its heights ``h`` were edited in place (e.g. a face slumped): keeps the bound of the cheap
        :meth:`reaches` test."""
        self._top = max(self._top, float(self.h.max()))

    def deposit(self, x: float, volume: float, spread: float) -> None:
        """Drop ``volume`` (m³) evenly over ``spread`` (m) around x; material off the grid is not kept."""
        sel = np.abs(self.x - x) <= max(spread / 2, self.dx)
        if sel.any() and volume > 0:
            self.h[sel] += volume / (sel.sum() * self.dx * self.width)
            self._top = max(self._top, float(self.h[sel].max()))
