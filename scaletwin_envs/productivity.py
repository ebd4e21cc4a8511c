"""Published loading-cycle figures, each with its source, and the productivity band they give a machine.

The hourly production of a wheel loader loading trucks, by the handbook formula (Komatsu Specifications &
Application Handbook, "Dozer shovels and wheel loaders": Q = q · 60 · E / Cm, q = heaped capacity × bucket fill
factor K, Cm in minutes), in mass per hour:

    Q [t/h] = ρ [t/m³] · V [m³] · K · 3600 / T [s] · E

Inputs of :func:`productivity_band`, with their sources (:data:`PUBLISHED`):

- K, bucket fill factor: 0.85–1.1, "average" to "easy" loading from a stockpile (Komatsu, table 3; gravel and clay
  from a stockpile are "average").
- T, cycle time: 30 s, the "optimum industry standard" from bucket fill to bucket dump (ForConstructionPros, a
  Caterpillar application specialist) and a good operator's fill-dump-return of a 2.3 m³ loader (Construction
  Equipment, a Caterpillar trainer), to 55 s, the top of Caterpillar's 45–55 s basic cycle (load, dump, manoeuvre).
  The figures are quoted for a 2.3 m³ (3 yd³) loader, whose boom is taken as :data:`REFERENCE_BOOM_M` (an
  assumption: the er12's 2.29 m boom carries 0.53 m³). Another size gets them Froude-scaled, T ∝ √L (equal
  Froude times, as every dynamic quantity of this package scales): an assumption, not a published figure, and the
  only way to give a scale model (the ``mini``) a band at all.
- E, job efficiency: 1 for simulated time (no operator breaks, no truck exchanges); a job hour of 50 working
  minutes is E = 50/60 (Caterpillar Performance Handbook).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from scaletwin_envs.specs.loader import GRAVITY

#: (figure, source, address) of every published number used here and in the loading-cycle benchmark.
PUBLISHED: tuple[tuple[str, str, str], ...] = (
    (
        "≤ 30 s from bucket fill to bucket dump: 'optimum industry standard' cycle "
        "(Caterpillar application specialist)",
        "ForConstructionPros, 'Optimizing Wheel Loader Cycle Times: When Even Seconds Count'",
        "https://www.forconstructionpros.com/equipment/earthmoving/loaders/article/12129273/"
        "optimizing-wheel-loader-cycle-times-when-even-seconds-count",
    ),
    (
        "30 s fill-dump-return for a 3 yd³ (2.3 m³) loader into 9 yd³ trucks, 50 working minutes an hour: 133 "
        "truckloads in 4 h; 2-3 passes per truck optimal; 85 % fill needs 3.5 passes",
        "Construction Equipment, 'Take-Charge Wheel Loader Operators Fill Trucks Faster' (2010, Caterpillar trainer)",
        "https://constructionequipment.com/take-charge-wheel-loader-operators-fill-trucks-faster",
    ),
    (
        "basic cycle time (load, dump, maneuver) of 45 to 55 s (Caterpillar estimate)",
        "Caterpillar, 'Four Ways to Crank Up Your Load & Haul Productivity'",
        "https://www.catallday.com/articles/challenges/worksite-productivity/"
        "four-ways-to-crank-up-your-load-haul-productivity",
    ),
    (
        "Q = q·60·E/Cm; bucket fill factor 1.0-1.1 easy, 0.85-0.95 average (unscreened gravel, clay), 0.75-0.8 "
        "difficult loading",
        "Komatsu Specifications & Application Handbook, 'Dozer shovels and wheel loaders'",
        "https://ru.scribd.com/document/143810369/komat",
    ),
    (
        "basic cycle time plus material/pile/operation adjustments in minutes (e.g. +0.02 min truck-dumped pile); "
        "job efficiency: 50 working minutes an hour (83 %)",
        "Caterpillar Performance Handbook, ed. 40, p. 12-106 'Wheel Loader - Cycle Time'",
        "https://www.scribd.com/doc/305991987/Wheel-Loader-Cycle-Time",
    ),
)
#: s: published short truck-loading cycle, fastest (the 30 s optimum) and slowest (Caterpillar's 55 s basic cycle).
CYCLE_S: tuple[float, float] = (30.0, 55.0)
#: Bucket fill factor, "average" to "easy" loading (Komatsu handbook, table 3).
FILL_FACTOR: tuple[float, float] = (0.85, 1.1)
#: m: boom length assumed for the 2.3 m³ (3 yd³) loader the cycle times are quoted for.
REFERENCE_BOOM_M = 2.6
#: Job efficiency of a 50-minute working hour (Caterpillar Performance Handbook).
JOB_HOUR = 50.0 / 60.0


@dataclass(frozen=True)
class ProductivityBand:
    """Published productivity band of one machine in one soil.

    Attributes:
        low, high: t/h at the slowest cycle and lowest fill factor, and at the fastest cycle and highest fill factor.
        cycle_s: (fastest, slowest) cycle time applied, s (Froude-scaled to the machine's boom).
        cycle_froude: the same in Froude times √(L/g) (the same at every size).
        bucket_t: tonnes in one heaped bucket (fill factor 1).
    """

    low: float
    high: float
    cycle_s: tuple[float, float]
    cycle_froude: tuple[float, float]
    bucket_t: float

    def position(self, t_per_h: float) -> str:
        """``"below"``, ``"inside"`` or ``"above"`` the band."""
        return "below" if t_per_h < self.low else "above" if t_per_h > self.high else "inside"


def hourly_production(bucket_m3: float, density_t_m3: float, fill_factor: float, cycle_s: float,
                      efficiency: float = 1.0) -> float:
    """The handbook's hourly production, t/h: ρ · V · K · 3600 / T · E (see the module docstring); ``bucket_m3``
    heaped capacity, ``density_t_m3`` loose density, ``cycle_s`` one pass, s; ``efficiency`` working fraction."""
    for name, value in (("bucket_m3", bucket_m3), ("density_t_m3", density_t_m3), ("fill_factor", fill_factor),
                        ("cycle_s", cycle_s), ("efficiency", efficiency)):
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return density_t_m3 * bucket_m3 * fill_factor * 3600.0 / cycle_s * efficiency


def productivity_band(bucket_m3: float, density_kg_m3: float, boom_m: float) -> ProductivityBand:
    """The published band (t/h of working time, E = 1) for a machine with a ``bucket_m3`` heaped bucket and a
    ``boom_m`` boom loading soil of loose density ``density_kg_m3`` (kg/m³): :data:`CYCLE_S` Froude-scaled from
    :data:`REFERENCE_BOOM_M` to ``boom_m``, :data:`FILL_FACTOR`."""
    if not (math.isfinite(boom_m) and boom_m > 0.0):
        raise ValueError(f"boom_m must be a positive finite number, got {boom_m!r}")
    ratio = math.sqrt(boom_m / REFERENCE_BOOM_M)
    fast, slow = (c * ratio for c in CYCLE_S)
    rho = density_kg_m3 / 1e3
    froude = math.sqrt(REFERENCE_BOOM_M / GRAVITY)
    return ProductivityBand(
        low=hourly_production(bucket_m3, rho, FILL_FACTOR[0], slow),
        high=hourly_production(bucket_m3, rho, FILL_FACTOR[1], fast),
        cycle_s=(fast, slow),
        cycle_froude=(CYCLE_S[0] / froude, CYCLE_S[1] / froude),
        bucket_t=rho * bucket_m3,
    )
