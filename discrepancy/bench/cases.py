"""Benchmark cases: what is planted (hidden from the tool), on which machine and soil, read through which sensors
(noise family) and delivered how (input condition).

Magnitudes are drawn in the effects' dimensionless groups Π, log-uniform over at least
:data:`MIN_DECADES` decades per effect (:data:`RANGES`, from near the detection limit to far above it), with a random
sign for signed parameters, so the same case mix is equally hard at every scale. Machines are presets or float
length ratios λ (:data:`FLOAT_SCALES`); soils are every named soil. Out-of-catalogue physics
(:data:`OUT_OF_CATALOGUE`) is planted through run-time terms the catalogue has no entry for.

The case list is deterministic from the master seed and prefix-stable (case ``i`` does not depend on how many cases
are run). Kinds follow a fixed interleaved pattern (:data:`KIND_PATTERN`); within each kind the noise families and
the input conditions are dealt in seeded shuffled rounds, so every family and condition gets its share of every
kind (nulls included) even in a short run.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from discrepancy.bench.logs import CONDITIONS, Condition, draw_condition
from discrepancy.bench.sensor_noise import FAMILIES, NoiseSpec, draw_noise
from discrepancy.data.channels import COMPARED, ROUTE2
from discrepancy.effects import CATALOGUE, Effect, Scales
from discrepancy.twin.env import PhysicsParams
from discrepancy.twin.spec import TwinSpec
from scaletwin_envs.specs import SOILS, make_loader, make_soil, preset_names

#: Float length ratios λ relative to the ER12 (issue 14: 0.5–2.0), drawn log-uniform; half the cases use a preset.
FLOAT_SCALES = (0.5, 2.0)
#: Share of cases on a preset machine (the rest on a float λ).
PRESET_SHARE = 0.5
#: Kinds in a fixed interleaved order of 20: 6 nulls (30 %, more than the old 15 %, so every noise family gets
#: nulls enough to test the ≥ 95 % target), 8 single, 3 double, 3 out-of-catalogue.
KIND_PATTERN = ("null", "single", "double", "single", "ooc", "null", "single", "null", "single", "double",
                "ooc", "single", "null", "single", "double", "null", "single", "ooc", "single", "null")
#: Signals a sensor fault is planted on (channels a real machine measures directly); also what may go missing.
SENSED = ("F21", "F31", "Pf_lift", "Pf_tilt", "p_lift", "p_tilt", "lift_extension", "tilt_extension", "boom_angle",
          "bucket_pitch", "travel_speed", "F21_x", "F31_z")
#: Each drawn range spans at least this many decades (issue 14: near the detection limit to far above it).
MIN_DECADES = 1.5
#: Planted magnitude range in Π per (effect, parameter), log-uniform; signed parameters get a random sign. Each
#: spans ≥ 1.5 decades: the lower ends are 3–4× below the old benchmark's (which sat just above what the tool
#: located), the upper ends 2–3× above its upper ends, kept physical (mass error < 1, |gain error| < 0.5).
RANGES: dict[tuple[str, str], tuple[float, float, bool]] = {
    ("coulomb_friction", "friction"): (0.001, 0.035, False),
    ("viscous_damping", "damping"): (0.003, 0.1, False),
    ("backlash", "clearance"): (0.0003, 0.01, False),
    ("actuator_delay", "delay"): (0.02, 0.7, False),
    ("hydraulic_compliance", "compliance"): (0.0015, 0.05, False),
    ("payload_mass_error", "mass_error"): (0.02, 0.65, True),
    ("payload_com_offset", "dx"): (0.006, 0.2, True),
    ("payload_com_offset", "dz"): (0.006, 0.2, True),
    ("soil_cohesion", "cohesion"): (0.006, 0.2, False),
    ("soil_adhesion", "adhesion"): (0.006, 0.2, False),
    ("sensor_bias", "bias"): (0.02, 0.65, True),
    ("sensor_gain", "gain_error"): (0.01, 0.35, True),
    ("sensor_delay", "delay"): (0.03, 1.0, False),
}
#: A soil term smaller than the soil's own is raised to a fraction of it, log-uniform over 1.5 decades: 3–100 %.
SOIL_OWN_SHARE = (0.03, 1.0)
OUT_OF_CATALOGUE = ("boom_spring", "edge_drag_v2", "soft_tilt_servo")
#: Relative size of each out-of-catalogue term (widened about 2× each way around the old ranges).
OOC_RANGES = {"boom_spring": (0.025, 0.4), "edge_drag_v2": (0.05, 0.8), "soft_tilt_servo": (0.005, 0.1)}
#: Channels a case's noise is drawn for (everything a recording carries).
CHANNELS = (*COMPARED, *ROUTE2)

Planted = tuple[tuple[str, str, tuple[tuple[str, float], ...]], ...]


@dataclass(frozen=True)
class Case:
    """One benchmark case (all seeds fixed): the twin, the hidden physics, the sensors and the input condition."""

    index: int
    kind: str
    twin: TwinSpec
    noise: NoiseSpec
    condition: Condition = field(default_factory=Condition)
    planted: Planted = ()  # (effect, target, ((param, Π), ...))
    ooc: str | None = None
    ooc_size: float = 0.0
    held_out_seed: int = 0
    seed: int = 0  # the master seed of the benchmark
    meta: dict[str, str] = field(default_factory=dict, compare=False)

    def effects(self, scales: Scales) -> list[Effect]:
        """The planted effects in SI for ``scales`` (sensor faults are relative to each signal's spread; a soil
        term is raised to :data:`SOIL_OWN_SHARE` of the soil's own term when that is larger, or it would not
        show)."""
        out = []
        for name, target, pis in self.planted:
            values = dict(pis)
            if name in ("soil_cohesion", "soil_adhesion"):
                key = name.removeprefix("soil_")
                own = getattr(scales, key) / (scales.unit_weight * scales.length)
                lo, hi, _ = RANGES[(name, key)]
                frac = np.log(values[key] / lo) / np.log(hi / lo)  # position in the drawn range, 0..1
                share = SOIL_OWN_SHARE[0] * (SOIL_OWN_SHARE[1] / SOIL_OWN_SHARE[0]) ** frac
                values[key] = max(values[key], own * float(share))
            out.append(Effect.from_pi(name, target, values, scales))
        return out

    def extra(self) -> PhysicsParams:
        """Out-of-catalogue run-time physics (nothing for catalogue cases)."""
        return ooc_physics(self.ooc, self.ooc_size, self.twin) if self.ooc else PhysicsParams()

    def describe(self) -> dict[str, Any]:
        """Everything that defines the case, JSON-able (the noise and condition in full)."""
        return {"index": self.index, "seed": self.seed, "kind": self.kind, "scale": self.meta.get("scale"),
                "soil": self.meta.get("soil"), "twin_seed": self.twin.seed, "held_out_seed": self.held_out_seed,
                "planted": [[n, t, [list(p) for p in pis]] for n, t, pis in self.planted], "ooc": self.ooc,
                "ooc_size": self.ooc_size, "noise": asdict(self.noise), "condition": asdict(self.condition)}

    def key(self) -> str:
        """A fingerprint of :meth:`describe`: a rerun skips a case only if it is the very same case."""
        text = json.dumps(self.describe(), sort_keys=True, default=str)
        return f"{self.seed}:{self.index}:{hashlib.sha256(text.encode()).hexdigest()[:12]}"


def ooc_physics(name: str, size: float, twin: TwinSpec) -> PhysicsParams:
    """An out-of-catalogue term of relative size ``size``: a torsional spring in the boom hinge, a velocity-squared
    drag on the cutting edge in the pile (soil-stiffness-like), or a tilt valve with a softer pressure–flow gain."""
    loader = twin.loader
    f_lift, length = loader.lift.max_extend_force, loader.characteristic_length
    if name == "boom_spring":
        return PhysicsParams(stiffness={"boom_hinge": size * f_lift * length})
    if name == "edge_drag_v2":
        return PhysicsParams(edge_drag=size * f_lift / loader.travel_speed**2)
    if name == "soft_tilt_servo":
        return PhysicsParams(servo_gain={"tilt": size})
    raise ValueError(f"unknown out-of-catalogue effect {name!r}; known {OUT_OF_CATALOGUE}")


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _magnitude(rng: np.random.Generator, key: tuple[str, str]) -> float:
    lo, hi, signed = RANGES[key]
    return _log_uniform(rng, lo, hi) * (float(rng.choice((-1.0, 1.0))) if signed else 1.0)


def random_effect(rng: np.random.Generator, exclude: frozenset[str] | set[str] = frozenset()
                  ) -> tuple[str, str, tuple[tuple[str, float], ...]]:
    """A catalogue effect at a random target and magnitude Π (not one of ``exclude``)."""
    name = str(rng.choice([n for n in CATALOGUE if n not in exclude]))
    spec = CATALOGUE[name]
    target = str(rng.choice(SENSED)) if spec.target_kind == "signal" else str(rng.choice(spec.targets))
    return name, target, tuple((p.name, _magnitude(rng, (name, p.name))) for p in spec.params)


def _dealt(seed: int, kind: str, slot: int, deck: tuple[str, ...], salt: int) -> str:
    """The ``slot``-th card of shuffled rounds of ``deck`` for ``kind`` (each round a fresh seeded shuffle)."""
    rnd, pos = divmod(slot, len(deck))
    order = np.random.default_rng([seed, salt, KIND_PATTERN.index(kind), rnd]).permutation(len(deck))
    return deck[int(order[pos])]


def make_case(index: int, seed: int, families: tuple[str, ...] = FAMILIES,
              conditions: tuple[str, ...] = CONDITIONS) -> Case:
    """Case ``index`` of the benchmark with master seed ``seed``, its family and condition dealt from
    ``families`` and ``conditions``.

    Raises:
        ValueError: an empty or unknown family or condition.
    """
    bad = [f for f in families if f not in FAMILIES] + [c for c in conditions if c not in CONDITIONS]
    if bad or not families or not conditions:
        raise ValueError(f"unknown or no families/conditions {bad}; known {FAMILIES} and {CONDITIONS}")
    kind = KIND_PATTERN[index % len(KIND_PATTERN)]
    slot = (index // len(KIND_PATTERN)) * KIND_PATTERN.count(kind) + KIND_PATTERN[: index % len(KIND_PATTERN)].count(
        kind)  # how many earlier cases have this kind
    family, condition = _dealt(seed, kind, slot, families, 1), _dealt(seed, kind, slot, conditions, 2)
    rng = np.random.default_rng([seed, index])
    if rng.uniform() < PRESET_SHARE:
        scale: str | float = str(rng.choice(preset_names()))
        scale_label = scale
    else:
        scale = round(_log_uniform(rng, *FLOAT_SCALES), 3)
        scale_label = f"λ={scale:g}"
    soil = str(rng.choice(sorted(SOILS)))
    twin = TwinSpec(make_loader(scale), make_soil(soil), {}, int(rng.integers(1, 10_000)))
    effects: list[tuple[str, str, tuple[tuple[str, float], ...]]] = []
    ooc, size = None, 0.0
    if kind in ("single", "double"):
        effects.append(random_effect(rng))
    if kind == "double":
        effects.append(random_effect(rng, exclude={effects[0][0]}))
    if kind == "ooc":
        ooc = str(rng.choice(OUT_OF_CATALOGUE))
        size = _log_uniform(rng, *OOC_RANGES[ooc])
    noise = draw_noise(np.random.default_rng([seed, index, 7]), family, CHANNELS)
    faulty = {t for n, t, _ in effects if CATALOGUE[n].target_kind == "signal"}
    cond = draw_condition(np.random.default_rng([seed, index, 11]), condition,
                          tuple(s for s in SENSED if s not in faulty))
    return Case(index, kind, twin, noise, cond, tuple(effects), ooc, size, twin.seed + 5000, seed,
                {"scale": scale_label, "soil": soil})


def make_cases(n: int, seed: int, families: tuple[str, ...] = FAMILIES,
               conditions: tuple[str, ...] = CONDITIONS) -> list[Case]:
    """The first ``n`` cases of master seed ``seed`` (see the module docstring)."""
    return [make_case(i, seed, families, conditions) for i in range(n)]
