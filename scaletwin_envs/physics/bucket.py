"""Bucket volume and the position of the material it carries (planar cross-section × width)."""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from scaletwin_envs.specs.loader import LinkageGeometry

HEAP_SLOPE = 0.5  # rise over run of the heap above the strike line (1:2, ISO 7546 / SAE J742)


def _section(g: LinkageGeometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.asarray(g.bucket_heel), np.asarray(g.bucket_edge), np.asarray(g.bucket_back_top)


def struck_area(g: LinkageGeometry) -> float:
    """Cross-section below the strike line (edge to top of the back wall), m²."""
    heel, edge, top = _section(g)
    a, b = edge - heel, top - heel
    return 0.5 * abs(float(a[0] * b[1] - a[1] * b[0]))


def heap_area(g: LinkageGeometry) -> float:
    """Triangular heap at a 1:2 slope on the strike line, m²."""
    _, edge, top = _section(g)
    span = float(np.linalg.norm(edge - top))
    return 0.25 * span * span * HEAP_SLOPE


def heaped_capacity(g: LinkageGeometry) -> float:
    """Rated heaped volume, m³."""
    return (struck_area(g) + heap_area(g)) * g.bucket_width


def load_centroid(g: LinkageGeometry, fill: float) -> np.ndarray:
    """Centroid (x, z) of the load in the reference pose for a volume fill fraction in [0, 1.2], m.

    Material settles into the corner between floor and back wall first, so the centroid moves from the
    struck triangle's heel region towards the heaped section's centroid as the bucket fills.
    """
    return np.array(centroid_at(centroid_ends(g), fill))


def centroid_at(ends: tuple[tuple[float, float], tuple[float, float]], fill: float) -> tuple[float, float]:
    """:func:`load_centroid` (x, z, m) from the :func:`centroid_ends` of the bucket, as Python floats (an env
    calls it every step while the bucket fills)."""
    (cx, cz), (hx, hz) = ends
    f = min(max(float(fill), 0.0), 1.0)
    return cx + (hx - cx) * f, cz + (hz - cz) * f


def centroid_ends(g: LinkageGeometry) -> tuple[tuple[float, float], tuple[float, float]]:
    """Load centroid (x, z, m; reference pose) of a nearly empty and of a heaped bucket."""
    corner_c, full_c = _centroid_ends(g)
    return (float(corner_c[0]), float(corner_c[1])), (float(full_c[0]), float(full_c[1]))


@lru_cache(maxsize=32)
def _centroid_ends(g: LinkageGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Load centroid of a nearly empty and of a heaped bucket, m (reference pose)."""
    heel, edge, top = _section(g)
    struck_c = (heel + edge + top) / 3.0
    mid = 0.5 * (edge + top)
    normal = np.array([-(top - edge)[1], (top - edge)[0]])
    normal = normal / (np.linalg.norm(normal) or 1.0)
    if np.dot(normal, mid - heel) < 0:
        normal = -normal
    heap_c = mid + normal * (math.sqrt(heap_area(g) / HEAP_SLOPE) * HEAP_SLOPE / 3.0)
    a_s, a_h = struck_area(g), heap_area(g)
    full_c = (struck_c * a_s + heap_c * a_h) / (a_s + a_h)
    return heel + (struck_c - heel) * 0.55, full_c


def capacity_fraction(pitch: float, rack_back: float = 0.35) -> float:
    """Fraction of the heaped capacity the bucket holds at a pitch (rad, + curled back) before spilling.

    Curled back past ``rack_back`` the full heap is held (plus 10 % heaped above rating); level, the heap
    slides off over the edge (≈ struck volume); tipped forward the struck volume drains until, at about
    −0.9 rad, the bucket is empty (dumping).
    """
    if pitch >= rack_back:
        return 1.1
    if pitch >= 0.0:
        return 0.75 + 0.35 * pitch / rack_back
    return max(0.0, 0.75 * (1.0 + pitch / 0.9))
