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
        k, top = int(u), self._last - 1
        k = top if top < k else k
        t = u - k
        return h.item(k) * (1.0 - t) + h.item(k + 1) * t  # Python floats: the same float64 arithmetic, faster

    @property
    def volume(self) -> float:
        """Material left in the strip, m³."""
        return float(self.h.sum() * self.dx * self.width)

    def reaches(self, polygon: np.ndarray) -> bool:
        """Cheap test: could the polygon (N×2, x–z) hold any pile material?"""
        pts = polygon.tolist()
        return max(x for x, _ in pts) >= self._x0 and min(z for _, z in pts) < self._top

    def overlap(self, polygon: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cell indices and heights (m) of pile material lying inside a convex polygon (N×2, x–z).

        A vertical line at a cell meets the polygon's edges at its bottom and top: each non-vertical edge is
        intersected with every cell's line at once (edges × cells), and the lowest and highest intersection
        bound the polygon there."""
        pts = polygon.tolist()
        xs_poly = [x for x, _ in pts]
        lo, hi = min(xs_poly), max(xs_poly)
        first = max(math.ceil((lo - self._x0) / self.dx), 0)
        last = min(math.floor((hi - self._x0) / self.dx), self._last)
        idx = np.arange(first, last + 1)
        if idx.size == 0:
            return idx, np.zeros(0)
        if self.h[first:last + 1].max() <= min(z for _, z in pts):  # the surface lies below the polygon here
            return idx, np.zeros(idx.size)
        n = len(pts)
        edges = []  # per non-vertical edge: start x, z and its run and rise, m
        for (x0, z0), (x1, z1) in ((pts[k], pts[(k + 1) % n]) for k in range(n)):
            if abs(x1 - x0) >= 1e-12:
                edges.append((x0, z0, x1 - x0, z1 - z0))
        if not edges:
            return idx, np.zeros(idx.size)
        x0, z0, run, rise = np.array(edges).T[:, :, None]  # each (edges, 1)
        t = (self.x[first:last + 1] - x0) / run  # (edges, cells): where each edge crosses each cell's line
        z = z0 + t * rise
        crosses = (t >= 0.0) & (t <= 1.0)
        z_lo = np.minimum.reduce(z, axis=0, initial=np.inf, where=crosses)
        z_hi = np.maximum.reduce(z, axis=0, initial=-np.inf, where=crosses)
        # a line that misses the polygon has z_lo = +inf or z_hi = -inf, so its material above z_lo is -inf: none
        return idx, np.maximum(np.minimum(self.h[first:last + 1], z_hi) - z_lo, 0.0)

    def remove(self, idx: np.ndarray, heights: np.ndarray) -> float:
        """Take material from columns (the material above slides down); returns the volume removed, m³."""
        self.h[idx] = np.maximum(self.h[idx] - heights, 0.0)  # what clip(min=0) computes, without its wrapper
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
