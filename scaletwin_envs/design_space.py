"""The product-line design space: machines that differ in design, not only in size.

A real loader line is not one layout at several sizes. Machines of one maker differ in linkage proportions,
cylinder sizing, relief pressure, pump flow, mass and its distribution, bucket, traction and travel speed. A
:class:`DesignSpace` draws such machines: a size λ (length ratio vs the ER12) on the product-line law
(:data:`~scaletwin_envs.specs.laws.PRODUCT_LINE`), then independent *distortions* on top of it, each recorded in
the sample's :attr:`ProductLineMachine.distortion` vector (dimensionless; 1.0 or 0.0 = the law's value):

* ``pin.<name>.x`` / ``pin.<name>.z``: a pin moved by this many boom lengths (linkage proportions). The boom
  pivot and O stay where they are (they define the boom length, the machine's characteristic length);
* ``lift_bore``, ``tilt_bore``: piston diameters ×; ``pressure``: relief pressure ×; ``lift_flow``,
  ``tilt_flow``: pump flow per circuit ×; ``lift_range``: boom raise angle ×;
* ``mass``: operating mass ×; ``boom_mass``, ``bucket_mass``: that body's mass × on top (mass distribution);
* ``bucket_size``: bucket shell ×; ``bucket_depth``: back-wall height × (bucket shape);
* ``traction``: rimpull / weight ×; ``travel_speed``: ×.

Cylinder strokes and closed lengths follow each sampled linkage: they are set so that the boom sweeps the ER12's
raise angle (× ``lift_range``) and the bucket the ER12's tilt range at the lowered boom, so the same scripted
cycle (thresholds in fractions of stroke) runs on every sample.

A sample is kept only if it is *valid* (:func:`check_design`):

* the Z-bar assembles over the whole dig workspace (every pair of cylinder lengths on a grid over both strokes);
* heaped bucket volume per operating mass 0.12–0.25 m³/t (``shared/reference/physics.md``: 0.13–0.23 across
  WA250, CAT 950 GC and WA475-10 spec sheets; the band is widened by 0.01 on each side for estimate error);
* breakout force / operating weight 0.6–1.1 (``physics.md``: rule of thumb 0.7–1.0 for 3–20 t machines; widened
  to cover the 0.6–0.7 of 20–50 t machines, which the same note says fall with size);
* full raise time 5–7 s for 3–30 t machines (``physics.md``: cycle times stay nearly constant in seconds; the
  ER12 on the estimate hydraulics raises in 6.4 s). Outside 3–30 t no band is claimed;
* no dead centre within the strokes: the tilt linkage's force ratio F21 / tilt force
  (:func:`~scaletwin_envs.physics.kinematics.tilt_ratio`) stays in 0.6–2.0 at every assembled pair of cylinder
  lengths on a 17 × 17 grid over both strokes. The ER12 spans 1.02–1.33; near a dead centre the ratio collapses
  to 0 or diverges, the cylinder can neither hold nor move the bucket there, and the simulated linkage jumps to
  its other assembly branch (a design rule of ours, no published band). The dead centre lies at the edge of the
  region where the linkage closes, which can fall between the points of a coarse grid: on a 9 × 9 grid one
  machine of 42 (drawn with seed 1) passed with a ratio of 0.73 while a 17 × 17 grid finds 0.35, and its simulated
  linkage jumped branch under a rack-back at relief, off by 40 % from its own statics on half its rows.
  The other dead centre, link B in line with the bucket's lever, lies inside the strokes of every layout (the
  ER12's too: a full rack-back at a raised boom came within 3° of it): the ratio stays finite there, so this
  check cannot see it. The builder's bucket stop keeps every machine 10° short of it
  (:func:`~scaletwin_envs.physics.kinematics.bucket_stops`; it cuts 1–5 of the ~200 stroke-grid poses of each
  machine drawn with seeds 0, 1 and 19, and none of the presets' scripted dig).

Rejected draws are counted (:attr:`ProductLineMachine.rejected`); sampling is seeded and reproducible: sample
``i`` of :meth:`DesignSpace.sample` depends only on ``(seed, i)``.
"""

from __future__ import annotations

import functools
import hashlib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from scaletwin_envs.physics.bucket import heaped_capacity
from scaletwin_envs.physics.kinematics import (
    LinkagePose,
    LinkageUnreachable,
    boom_angle_for_lift_length,
    pose_from_cylinders,
    solve_pose,
    tilt_ratio,
)
from scaletwin_envs.physics.statics import breakout_force
from scaletwin_envs.specs import make_loader
from scaletwin_envs.specs.laws import PRODUCT_LINE
from scaletwin_envs.specs.loader import LoaderSpec, MassProperties

#: Pins a sample may move (the boom pivot and O define the boom and stay).
MOVABLE_PINS = ("bell_crank_pivot", "bell_crank_top", "bell_crank_bottom", "pin_21", "lift_frame_pin",
                "lift_boom_pin", "tilt_frame_pin")
#: Published bands (see the module docstring for sources).
BUCKET_M3_PER_T = (0.12, 0.25)
BREAKOUT_PER_WEIGHT = (0.6, 1.1)
RAISE_TIME_S = (5.0, 7.0)
RAISE_TIME_MASS_T = (3.0, 30.0)
#: Band of the tilt linkage's force ratio over the whole strokes (module docstring).
TILT_RATIO_BAND = (0.6, 2.0)
#: Grid points per cylinder stroke in the assembly check.
ASSEMBLY_GRID = 9
#: Grid points per cylinder stroke in the dead-centre check (finer: a dead centre hides between coarse points).
DEAD_CENTRE_GRID = 17
#: Draws tried per sample before giving up (a design space this narrow never needs more than a few).
MAX_DRAWS = 200
#: Decimal digits (m) the solved cylinder lengths of a design are rounded to: 1 nm, far below any physical effect,
#: far above the last-bit differences of the trigonometry between numpy/libm builds.
LENGTH_DIGITS = 9


def stroke_poses(spec: LoaderSpec, n: int = ASSEMBLY_GRID) -> list[LinkagePose]:
    """The assembled poses at every pair of cylinder lengths on an ``n`` × ``n`` grid over both strokes (pairs at
    which the linkage cannot close are skipped)."""
    poses = []
    for lift in np.linspace(spec.lift.closed_length, spec.lift.closed_length + spec.lift.stroke, n):
        for tilt in np.linspace(spec.tilt.closed_length, spec.tilt.closed_length + spec.tilt.stroke, n):
            try:
                poses.append(pose_from_cylinders(spec.geometry, float(lift), float(tilt)))
            except LinkageUnreachable:
                continue
    return poses


@functools.cache
def reference_workspace(n: int = ASSEMBLY_GRID) -> tuple[tuple[float, float], ...]:
    """The ER12's dig workspace as (boom angle, bucket angle relative to the boom) poses, rad: every pose at which
    its linkage closes on an ``n`` × ``n`` grid of both cylinders' lengths over their strokes."""
    return tuple((p.boom, p.bucket) for p in stroke_poses(make_loader("er12"), n))


@dataclass(frozen=True)
class Validity:
    """Which checks a design passes, with the measured values (units in the names)."""

    assembles: bool
    bucket_m3_per_t: float
    breakout_per_weight: float
    raise_time_s: float
    operating_mass_t: float
    tilt_ratio_range: tuple[float, float] = (float("nan"), float("nan"))
    reasons: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        return not self.reasons

    def to_dict(self) -> dict[str, Any]:
        return {"assembles": self.assembles, "bucket_m3_per_t": self.bucket_m3_per_t,
                "breakout_per_weight": self.breakout_per_weight, "raise_time_s": self.raise_time_s,
                "operating_mass_t": self.operating_mass_t, "tilt_ratio_min": self.tilt_ratio_range[0],
                "tilt_ratio_max": self.tilt_ratio_range[1], "reasons": list(self.reasons)}


def assembles_over_workspace(spec: LoaderSpec, workspace: Sequence[tuple[float, float]] | None = None) -> bool:
    """True when the linkage closes at every (boom, bucket) pose of ``workspace`` (rad; default: the ER12's dig
    workspace, :func:`reference_workspace`, with the boom angles stretched by the design's raise range)."""
    for boom, bucket in workspace if workspace is not None else _stretched_workspace(spec):
        try:
            solve_pose(spec.geometry, boom, bucket)
        except LinkageUnreachable:
            return False
    return True


def tilt_ratio_range(spec: LoaderSpec, n: int = ASSEMBLY_GRID) -> tuple[float, float]:
    """(min, max) of the tilt linkage's force ratio over :func:`stroke_poses` (1; NaN if none assembles)."""
    ratios = [tilt_ratio(spec.geometry, p.boom, p.bucket_pitch) for p in stroke_poses(spec, n)]
    return (float(min(ratios)), float(max(ratios))) if ratios else (float("nan"), float("nan"))


def _stretched_workspace(spec: LoaderSpec) -> list[tuple[float, float]]:
    poses = reference_workspace()
    lo = min(b for b, _ in poses)
    hi_ref = max(b for b, _ in poses)
    hi = boom_angle_for_lift_length(spec.geometry, spec.lift.closed_length + spec.lift.stroke)
    stretch = (hi - lo) / (hi_ref - lo)
    return [(lo + (b - lo) * stretch, k) for b, k in poses]


def check_design(spec: LoaderSpec) -> Validity:
    """Validity of a loader against the published bands (module docstring)."""
    reasons: list[str] = []
    mass_t = spec.operating_mass / 1000.0
    m3_per_t = heaped_capacity(spec.geometry) / mass_t
    raise_s = spec.lift.stroke / spec.lift.extend_speed
    ok_assembly = assembles_over_workspace(spec)
    if not ok_assembly:
        reasons.append("the linkage does not assemble over the dig workspace")
    breakout = breakout_force(spec) / spec.weight if ok_assembly else float("nan")
    ratio = tilt_ratio_range(spec, DEAD_CENTRE_GRID)
    lo, hi = TILT_RATIO_BAND
    if not lo <= ratio[0] <= ratio[1] <= hi:
        reasons.append(f"tilt linkage force ratio {ratio[0]:.2f}–{ratio[1]:.2f} leaves [{lo}, {hi}] within the "
                       "strokes (a dead centre)")
    lo, hi = BUCKET_M3_PER_T
    if not lo <= m3_per_t <= hi:
        reasons.append(f"bucket {m3_per_t:.3f} m³/t outside [{lo}, {hi}]")
    lo, hi = BREAKOUT_PER_WEIGHT
    if ok_assembly and not lo <= breakout <= hi:
        reasons.append(f"breakout / weight {breakout:.2f} outside [{lo}, {hi}]")
    lo, hi = RAISE_TIME_S
    if RAISE_TIME_MASS_T[0] <= mass_t <= RAISE_TIME_MASS_T[1] and not lo <= raise_s <= hi:
        reasons.append(f"full raise {raise_s:.2f} s outside [{lo}, {hi}] s for a {mass_t:.1f} t machine")
    return Validity(ok_assembly, float(m3_per_t), float(breakout), float(raise_s), float(mass_t), ratio,
                    tuple(reasons))


@dataclass(frozen=True)
class ProductLineMachine:
    """One sampled machine: its spec, the distortion vector it was drawn with and its validity.

    Attributes:
        name: ``"pl<seed>-<index>"``, unique per (seed, index).
        scale: λ, length ratio vs the ER12.
        distortion: every sampled factor or offset (module docstring), dimensionless.
        spec: the :class:`LoaderSpec` (``spec.provenance["design_space"]`` names the draw).
        validity: the checks it passed.  rejected: invalid draws discarded before it.
    """

    name: str
    scale: float
    distortion: Mapping[str, float]
    spec: LoaderSpec
    validity: Validity
    rejected: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "scale": self.scale, "distortion": dict(self.distortion),
                "spec": self.spec.to_dict(), "validity": self.validity.to_dict(), "rejected": self.rejected}


@dataclass(frozen=True)
class DesignSpace:
    """Ranges of a product line's sizes and design distortions (all dimensionless).

    Factors are drawn log-uniformly in ``[1/r, r]`` for a range ``r`` (``r = 1`` switches a factor off), pin
    offsets uniformly in ``±pin_offset`` boom lengths, λ log-uniformly in ``scale``.
    """

    scale: tuple[float, float] = (0.4, 2.4)
    pin_offset: float = 0.035
    bore: float = 1.15
    pressure: float = 1.12
    flow: float = 1.2
    lift_range: float = 1.06
    mass: float = 1.12
    body_mass: float = 1.25
    bucket_size: float = 1.12
    bucket_depth: float = 1.12
    traction: float = 1.25
    travel_speed: float = 1.25
    movable_pins: tuple[str, ...] = MOVABLE_PINS
    name: str = "product_line"

    def __post_init__(self) -> None:
        lo, hi = self.scale
        if not (0.05 <= lo <= hi <= 3.0):
            raise ValueError(f"scale range must lie in [0.05, 3.0] with lo <= hi, got {self.scale}")
        for k in ("bore", "pressure", "flow", "lift_range", "mass", "body_mass", "bucket_size", "bucket_depth",
                  "traction", "travel_speed"):
            if not getattr(self, k) >= 1.0:
                raise ValueError(f"DesignSpace.{k} is a range factor r >= 1 (draws in [1/r, r]), "
                                 f"got {getattr(self, k)}")
        if not 0.0 <= self.pin_offset <= 0.1:
            raise ValueError(f"pin_offset must be in [0, 0.1] boom lengths, got {self.pin_offset}")
        bad = sorted(set(self.movable_pins) - set(MOVABLE_PINS))
        if bad:
            raise ValueError(f"unknown movable pins {bad}; accepted: {list(MOVABLE_PINS)}")

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in (
            "scale", "pin_offset", "bore", "pressure", "flow", "lift_range", "mass", "body_mass", "bucket_size",
            "bucket_depth", "traction", "travel_speed", "movable_pins", "name")}

    # ------------------------------------------------------------------------------------------- drawing

    def draw(self, rng: np.random.Generator) -> dict[str, float]:
        """One distortion vector (not yet checked for validity)."""

        def factor(r: float) -> float:
            return float(math.exp(rng.uniform(-math.log(r), math.log(r)))) if r > 1.0 else 1.0

        lo, hi = self.scale
        d: dict[str, float] = {"scale": float(math.exp(rng.uniform(math.log(lo), math.log(hi))))}
        for pin in MOVABLE_PINS:
            for axis in ("x", "z"):
                moved = pin in self.movable_pins and self.pin_offset > 0
                d[f"pin.{pin}.{axis}"] = float(rng.uniform(-self.pin_offset, self.pin_offset)) if moved else 0.0
        for key, r in (("lift_bore", self.bore), ("tilt_bore", self.bore), ("pressure", self.pressure),
                       ("lift_flow", self.flow), ("tilt_flow", self.flow), ("lift_range", self.lift_range),
                       ("mass", self.mass), ("boom_mass", self.body_mass), ("bucket_mass", self.body_mass),
                       ("bucket_size", self.bucket_size), ("bucket_depth", self.bucket_depth),
                       ("traction", self.traction), ("travel_speed", self.travel_speed)):
            d[key] = factor(r)
        return d

    def sample_one(self, seed: int, index: int) -> ProductLineMachine:
        """Machine ``index`` of the line drawn with ``seed`` (the first valid draw of its own random stream)."""
        rng = np.random.default_rng([int(seed), int(index)])
        for rejected in range(MAX_DRAWS):
            d = self.draw(rng)
            name = f"pl{seed}-{index}"
            try:
                spec = build_design(d, name=name)
            except ValueError:
                continue
            validity = check_design(spec)
            if validity.ok:
                spec = replace(spec, provenance={**spec.provenance, "design_space": f"{self.name} seed={seed} "
                                                 f"index={index} draw={rejected} ({_digest(d)})"})
                return ProductLineMachine(name, d["scale"], d, spec, validity, rejected)
        raise RuntimeError(f"no valid design in {MAX_DRAWS} draws for seed={seed}, index={index}; "
                           "the design space is too wide for the validity bands")

    def sample(self, n: int, seed: int = 0) -> list[ProductLineMachine]:
        """``n`` valid machines (indices 0..n-1 of ``seed``)."""
        if n < 0:
            raise ValueError(f"n must be >= 0, got {n}")
        return [self.sample_one(seed, i) for i in range(n)]


def _digest(d: Mapping[str, float]) -> str:
    text = ",".join(f"{k}={v:.12g}" for k, v in sorted(d.items()))
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def build_design(distortion: Mapping[str, float], name: str = "design") -> LoaderSpec:
    """The loader of a distortion vector (:meth:`DesignSpace.draw`'s keys; missing keys = no distortion).

    Raises:
        ValueError: the vector is invalid (non-finite, factor <= 0, unknown key) or the linkage cannot be
            assembled at the ends of the ER12's boom and bucket ranges.
    """
    known = {"scale", *(f"pin.{p}.{a}" for p in MOVABLE_PINS for a in "xz"), "lift_bore", "tilt_bore", "pressure",
             "lift_flow", "tilt_flow", "lift_range", "mass", "boom_mass", "bucket_mass", "bucket_size",
             "bucket_depth", "traction", "travel_speed"}
    bad = sorted(set(distortion) - known)
    if bad:
        raise ValueError(f"unknown design keys {bad}")
    d = {k: float(v) for k, v in distortion.items()}
    for k, v in d.items():
        if not math.isfinite(v) or (not k.startswith("pin.") and v <= 0):
            raise ValueError(f"design[{k!r}] must be finite{'' if k.startswith('pin.') else ' and > 0'}, got {v}")
    scale = d.get("scale", 1.0)
    base = make_loader(scale, law=PRODUCT_LINE)
    L = base.geometry.boom_length
    geo = base.geometry
    moved = {}
    for pin in MOVABLE_PINS:
        x, z = getattr(geo, pin)
        moved[pin] = (x + d.get(f"pin.{pin}.x", 0.0) * L, z + d.get(f"pin.{pin}.z", 0.0) * L)
    depth = d.get("bucket_depth", 1.0)
    heel = geo.bucket_heel
    bx, bz = geo.bucket_back_top
    geo = replace(geo, **moved, bucket_back_top=(bx, heel[1] + (bz - heel[1]) * depth))
    geo = geo.scaled(1.0, d.get("bucket_size", 1.0))
    # Strokes follow the linkage: the boom sweeps the ER12's raise angle (× lift_range); the tilt cylinder spans
    # every pose of the ER12's dig workspace (boom angles stretched alike).
    poses = reference_workspace()
    b0, b1 = min(b for b, _ in poses), max(b for b, _ in poses)
    stretch = d.get("lift_range", 1.0)
    # Solved lengths are rounded to 1 nm (LENGTH_DIGITS): the solver's last bits differ between numpy/libm builds
    # (seen: 10 of 40 drawn machines' strokes 1-4e-16 m apart on another host), and a spec is part of the key its
    # recordings are filed under, so unrounded a shared data set would not be found, and be simulated again.
    try:
        lift_ends = sorted((round(solve_pose(geo, b0, 0.0).lift_length, LENGTH_DIGITS),
                            round(solve_pose(geo, b0 + (b1 - b0) * stretch, 0.0).lift_length, LENGTH_DIGITS)))
        tilts = [round(solve_pose(geo, b0 + (b - b0) * stretch, k).tilt_length, LENGTH_DIGITS) for b, k in poses]
    except LinkageUnreachable as exc:
        raise ValueError(f"design does not assemble over the dig workspace: {exc}") from exc
    base_tilts = [solve_pose(base.geometry, b, k).tilt_length for b, k in poses]
    lift = replace(base.lift, closed_length=lift_ends[0],
                   stroke=round(lift_ends[1] - lift_ends[0], LENGTH_DIGITS))
    # the law machine's tilt stroke reaches past its workspace's longest pose (the toggle side): keep that
    # proportion, so that a design without distortion is the law's machine
    span = (max(tilts) - min(tilts)) / (max(base_tilts) - min(base_tilts))
    tilt = replace(base.tilt, closed_length=round(min(tilts) + (base.tilt.closed_length - min(base_tilts)),
                                                  LENGTH_DIGITS),
                   stroke=round(base.tilt.stroke * span, LENGTH_DIGITS))
    lift = _resize_cylinder(lift, d.get("lift_bore", 1.0), d.get("pressure", 1.0), d.get("lift_flow", 1.0),
                            base.lift.stroke)
    tilt = _resize_cylinder(tilt, d.get("tilt_bore", 1.0), d.get("pressure", 1.0), d.get("tilt_flow", 1.0),
                            base.tilt.stroke)
    m = base.masses
    mass = d.get("mass", 1.0)
    lift, tilt = (replace(c, barrel_mass=c.barrel_mass * mass, rod_mass=c.rod_mass * mass) for c in (lift, tilt))
    masses = MassProperties(bucket=m.bucket * mass * d.get("bucket_mass", 1.0), link_b=m.link_b * mass,
                            bell_crank=m.bell_crank * mass, boom=m.boom * mass * d.get("boom_mass", 1.0),
                            chassis=m.chassis * mass)
    bucket_volume = d.get("bucket_size", 1.0) ** 3 * depth
    spec = LoaderSpec(
        name=name, scale=float(scale), geometry=geo, masses=masses, lift=lift, tilt=tilt,
        travel_speed=base.travel_speed * d.get("travel_speed", 1.0),
        traction_coefficient=base.traction_coefficient * d.get("traction", 1.0),
        rated_load=base.rated_load * mass * bucket_volume,
        provenance={**base.provenance, "scaling": f"design space draw on {base.name}",
                    "design": ", ".join(f"{k}={v:.4g}" for k, v in sorted(d.items()))},
    )
    return spec


def _resize_cylinder(cyl: Any, bore: float, pressure: float, flow: float, law_stroke: float) -> Any:
    """Bore × ``bore`` (rod with it), relief × ``pressure``; pump flow keeps the law's cylinder speed × ``flow``
    (the law's speed is its flow over its area; the stroke may have changed with the linkage, the speed not)."""
    law_speed = cyl.pump_flow / cyl.bore_area
    out = replace(cyl, bore=cyl.bore * bore, rod_diameter=cyl.rod_diameter * bore,
                  relief_pressure=cyl.relief_pressure * pressure)
    return replace(out, pump_flow=law_speed * flow * out.bore_area)

