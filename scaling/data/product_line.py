"""Scaling across a product line: many sampled machines, design-aware groups, matched pairs, grouped splits.

The paper trains δ1 on two machines of one design; a product line differs in linkage, hydraulics, masses, bucket
and traction (:mod:`scaletwin_envs.design_space`). This module turns such a line into δ1 learning data:

* :class:`ProductLine`: a seeded sample of the design space and the :class:`~scaling.data.recordings.DatasetSpec` that
  digs and holds with every machine (resumable, fanned out through the executor seam like every data set);
* :func:`add_design_signals`: per-row quantities that follow from the machine's *design* and its measured pose,
  dimensionless: ``tilt_ratio`` (F21 per tilt-cylinder force of the massless linkage at that pose,
  :func:`~scaletwin_envs.physics.kinematics.tilt_ratio`), ``tilt_stroke`` / ``lift_stroke`` (cylinder extension
  per stroke: where the end stops are) and ``fill`` (load / rated load). A maker knows its machines' drawings and
  every loader measures boom and bucket angles or cylinder strokes, so none of them needs a load pin; and
  ``F21_linkage`` = tilt_ratio · |Pf_tilt| (N), the pin force of the massless linkage, which normalises F21 in
  the output group :data:`PI1_LINKAGE` (the ML then learns only what the statics leave out: link weights,
  inertia, end stops);
* :func:`on_branch`: whether a row's recorded bucket pitch follows from its recorded boom angle and tilt-cylinder
  length on the design's assembly branch (``pitch_gap``, from :func:`add_design_signals`). Where it does not, the
  simulated linkage has left its branch (a simulator artefact: the Z-bar flipped over under a rack-back at relief)
  and the statics the design signals rest on do not hold: such rows are neither trained on, matched nor judged;
* :func:`match_rows`: for each target row the source row of the same kind (dig or hold) nearest in pose and fill:
  δ1 between matched rows measures the machines' difference, not the difference between two moments of a cycle;
* :func:`training_pairs`: every row of every machine as a target, with matched rows of other machines as sources,
  so that any calibrated machine can be the source;
* :func:`machine_folds`: grouped K-fold over machines (no machine on both sides).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Any

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

from scaletwin_envs.design_space import DesignSpace, ProductLineMachine
from scaletwin_envs.physics.bucket import heaped_capacity
from scaletwin_envs.physics.kinematics import LinkageUnreachable, bucket_angle_for_tilt_length, tilt_ratio
from scaletwin_envs.specs import make_loader
from scaletwin_envs.specs.loader import LoaderSpec
from scaling.data.delta_dataset import DeltaDataset, concat_datasets
from scaling.data.recordings import SOILS, DatasetSpec
from scaling.dimensions.groups import PiGroup

#: π1 normalised by the linkage statics: F21 / (tilt_ratio · |Pf_tilt|), ≈ 1 wherever the massless linkage holds.
PI1_LINKAGE = PiGroup({"F21": Fraction(1), "F21_linkage": Fraction(-1)}, name="pi1_linkage")
#: The linkage groups appended by the ``+linkage`` group sets (each a dimensionless variable by itself).
LINKAGE_GROUPS: tuple[PiGroup, ...] = tuple(PiGroup({v: Fraction(1)}, name=v)
                                            for v in ("tilt_ratio", "tilt_stroke", "lift_stroke"))
#: Columns a source row is matched on (after the row kind), in their units: rad, rad, 1.
MATCH_KEYS: tuple[str, ...] = ("boom_angle", "bucket_pitch", "fill")
#: Fill is weighted so that 10 % of rated load counts as much as 0.1 rad of pose.
MATCH_WEIGHTS: tuple[float, ...] = (1.0, 1.0, 1.0)
#: Largest ``pitch_gap`` (rad) of a row on the design's assembly branch. Measured on the 53 machines of the
#: leave-machine-out layout before the bucket stop (125,040 rows, design seeds 0 and 1): on 50 machines the gap is
#: the linkage's compliance under load (a machine's 99th percentile 0.010–0.052 rad, its largest 0.011–0.133 rad);
#: on four hold episodes of ``pl0-14``, ``pl0-24`` and ``pl0-25``, whose Z-bar flipped over in the final rack-back
#: at relief, 0.9–1.9 rad on 404 rows (none between 0.3 and 0.9 rad).
BRANCH_TOLERANCE = 0.3


@dataclass(frozen=True)
class ProductLine:
    """A seeded sample of ``n_machines`` from ``space`` and what each of them digs.

    Attributes:
        soils, pile_heights, dig_seeds: dig episodes per machine (every combination × ``dig_seeds``).
        hold_episodes, hold_poses: static-hold episodes per machine and carry poses per episode.
        presets: extra named machines added to the line (``("er12",)``), labelled by their preset name.
    """

    n_machines: int = 32
    seed: int = 0
    space: DesignSpace = field(default_factory=DesignSpace)
    soils: tuple[str, ...] = SOILS
    pile_heights: tuple[float, ...] = (0.6, 0.8)
    dig_seeds: int = 1
    hold_episodes: int = 4
    hold_poses: int = 3
    presets: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.n_machines < 0 or self.dig_seeds < 0 or self.hold_episodes < 0:
            raise ValueError("n_machines, dig_seeds and hold_episodes must be >= 0")

    @functools.cached_property
    def machines(self) -> tuple[ProductLineMachine, ...]:
        """The sampled machines (seeded: machine i depends on (seed, i) only)."""
        return tuple(self.space.sample(self.n_machines, self.seed))

    def specs(self) -> dict[str, LoaderSpec]:
        """Machine label → spec, presets included."""
        return {**{p: make_loader(p) for p in self.presets}, **{m.name: m.spec for m in self.machines}}

    def dataset_spec(self) -> DatasetSpec:
        """The episodes to simulate; machines are passed to the env as spec dictionaries (JSON)."""
        machines = tuple((p, p) for p in self.presets) + tuple((m.name, m.spec.to_dict()) for m in self.machines)
        return DatasetSpec(machines=machines, soils=self.soils, pile_heights=self.pile_heights,
                           dig_seeds=self.dig_seeds, hold_episodes=self.hold_episodes, hold_poses=self.hold_poses,
                           seed=1_000_000 * (self.seed + 1))

    def distortions(self) -> pd.DataFrame:
        """One row per sampled machine: its design vector (:meth:`DesignSpace.draw` keys) and validity values."""
        rows = [{"machine": m.name, **m.distortion, **{k: v for k, v in m.validity.to_dict().items()
                                                        if k not in ("reasons", "assembles")}}
                for m in self.machines]
        return pd.DataFrame(rows)

    def to_dict(self) -> dict[str, Any]:
        return {"n_machines": self.n_machines, "seed": self.seed, "space": self.space.to_dict(),
                "soils": list(self.soils), "pile_heights": list(self.pile_heights), "dig_seeds": self.dig_seeds,
                "hold_episodes": self.hold_episodes, "hold_poses": self.hold_poses, "presets": list(self.presets)}


def add_design_signals(frame: pd.DataFrame, specs: Mapping[str, LoaderSpec]) -> pd.DataFrame:
    """``frame`` with the design signals (:data:`~scaletwin_envs.signal_units.DESIGN_SIGNAL_UNITS`) computed from
    each row's machine spec and pose, and ``pitch_gap`` (rad): |the recorded bucket pitch − the pitch the design's
    linkage gives at the recorded boom angle and tilt-cylinder length| (NaN where it cannot be assembled there),
    which :func:`on_branch` reads.

    Args:
        frame: rows with ``machine``, ``boom_angle``, ``bucket_pitch`` (rad), ``lift_extension``,
            ``tilt_extension`` (m), ``m_load`` (kg) and ``Pf_tilt`` (N, positive pushing).
        specs: machine label → :class:`LoaderSpec` (the design each row was measured on).

    Raises:
        KeyError: a machine of ``frame`` has no spec, or a needed column is missing.
    """
    need = ["machine", "boom_angle", "bucket_pitch", "lift_extension", "tilt_extension", "m_load", "Pf_tilt"]
    if missing := [c for c in need if c not in frame.columns]:
        raise KeyError(f"design signals need columns {missing}")
    labels = frame["machine"].astype(str)
    if unknown := sorted(set(labels) - set(specs)):
        raise KeyError(f"no machine spec for {unknown}; pass specs for every machine of the frame")
    out = frame.copy()
    ratio, gap = np.full(len(frame), np.nan), np.full(len(frame), np.nan)
    for name, idx in labels.groupby(labels).indices.items():
        spec = specs[name]
        boom, pitch = frame["boom_angle"].to_numpy(float)[idx], frame["bucket_pitch"].to_numpy(float)[idx]
        ratio[idx] = [_ratio(spec, b, p) for b, p in zip(boom, pitch, strict=True)]
        length = spec.tilt.closed_length + frame["tilt_extension"].to_numpy(float)[idx]
        gap[idx] = [_pitch_gap(spec, b, p, n) for b, p, n in zip(boom, pitch, length, strict=True)]
    per_machine = {n: (s.lift.stroke, s.tilt.stroke, s.rated_load, s.tilt.max_extend_force, s.tilt.max_retract_force)
                   for n, s in specs.items()}
    lift_s, tilt_s, rated, push, pull = (labels.map({n: v[i] for n, v in per_machine.items()}).to_numpy(float)
                                         for i in range(5))
    out["tilt_ratio"] = ratio
    out["tilt_stroke"] = frame["tilt_extension"].to_numpy(float) / tilt_s
    out["lift_stroke"] = frame["lift_extension"].to_numpy(float) / lift_s
    out["fill"] = frame["m_load"].to_numpy(float) / rated
    out["F21_linkage"] = ratio * np.abs(frame["Pf_tilt"].to_numpy(float))
    out["pitch_gap"] = gap
    tilt = frame["Pf_tilt"].to_numpy(float)  # the loaded chamber's pressure over relief: piston side when pushing
    out["tilt_load"] = np.where(tilt >= 0, tilt / push, -tilt / pull)
    return out


def _ratio(spec: LoaderSpec, boom: float, pitch: float) -> float:
    try:
        return tilt_ratio(spec.geometry, float(boom), float(pitch))
    except LinkageUnreachable:
        return float("nan")


def _pitch_gap(spec: LoaderSpec, boom: float, pitch: float, tilt_length: float) -> float:
    """|pitch − the bucket pitch the design's linkage gives at ``boom`` (rad) and ``tilt_length`` (m, pin to pin)|,
    wrapped to [0, π] (rad); NaN where the linkage cannot close there."""
    try:
        bucket = bucket_angle_for_tilt_length(spec.geometry, float(boom), float(tilt_length))
    except LinkageUnreachable:
        return float("nan")
    return abs(float((pitch - boom - bucket + np.pi) % (2 * np.pi) - np.pi))


def on_branch(frame: pd.DataFrame, tolerance: float = BRANCH_TOLERANCE) -> np.ndarray:
    """Mask of the rows whose recorded bucket pitch the design's linkage gives at the recorded boom angle and
    tilt-cylinder length: ``pitch_gap`` (rad) at most ``tolerance`` (rad). Rows without the column (no design
    signals) and rows where the linkage cannot close at the recorded lengths (gap NaN: link B near straight under
    load, 908 rows at 69–87 % of the tilt stroke on the layout's machines) count as on the branch.

    Off the branch the simulated Z-bar has flipped over a dead centre: the pose the bucket pitch says is not one the
    cylinder lengths give, the linkage statics at that pose (``tilt_ratio``, ``F21_linkage``) describe another
    mechanism, and π1 = F21 / F21_linkage falls to 0.06 (``pl0-24``: predicted F21 430 times the simulated one).
    Seen in hold episodes (a rack-back at relief, a lowered boom curling the bucket on the ground) until the
    builder's bucket stop (:func:`scaletwin_envs.physics.kinematics.bucket_stops`); with it no row of the seed-0,
    seed-1 and seed-19 lines is off (largest gap 0.14 rad), and the mask stays as a guard.
    """
    if "pitch_gap" not in frame.columns:
        return np.ones(len(frame), dtype=bool)
    return ~(frame["pitch_gap"].to_numpy(float) > tolerance)


def match_rows(source: pd.DataFrame, target: pd.DataFrame, keys: Sequence[str] = MATCH_KEYS,
               weights: Sequence[float] = MATCH_WEIGHTS) -> np.ndarray:
    """Positional index into ``source`` of the matched row of every ``target`` row: same ``kind`` (when both
    have one; any kind where the source has none of it), nearest in the weighted ``keys``.

    Raises:
        KeyError: a key is missing.  ValueError: ``source`` is empty.
    """
    if len(source) == 0:
        raise ValueError("no source rows to match against")
    if missing := [k for k in keys if k not in source.columns or k not in target.columns]:
        raise KeyError(f"matching needs columns {missing} in source and target")
    w = np.asarray(weights, dtype=float)
    s = np.nan_to_num(source[list(keys)].to_numpy(float)) * w
    t = np.nan_to_num(target[list(keys)].to_numpy(float)) * w
    out = np.empty(len(target), dtype=np.int64)
    s_kind = source["kind"].astype(str).to_numpy() if "kind" in source.columns else np.full(len(source), "")
    t_kind = target["kind"].astype(str).to_numpy() if "kind" in target.columns else np.full(len(target), "")
    for kind in np.unique(t_kind):
        ti = np.nonzero(t_kind == kind)[0]
        si = np.nonzero(s_kind == kind)[0]
        if si.size == 0:
            si = np.arange(len(source))
        _, nearest = cKDTree(s[si]).query(t[ti])
        out[ti] = si[nearest]
    return out


def matched_pairs(source: pd.DataFrame, target: pd.DataFrame, output_group: PiGroup,
                  input_groups: Sequence[PiGroup], reference_id: int = 0) -> DeltaDataset:
    """Every ``target`` row paired with its matched ``source`` row (:func:`match_rows`)."""
    idx = match_rows(source, target)
    return DeltaDataset.from_matched(source.iloc[idx], target, output_group, input_groups,
                                     reference_id=reference_id)


def training_pairs(frame: pd.DataFrame, output_group: PiGroup, input_groups: Sequence[PiGroup],
                   n_sources: int = 1, seed: int = 0) -> DeltaDataset:
    """Pairs for learning δ1 across a product line: each machine's rows as targets, each with matched rows of
    ``n_sources`` other machines drawn at random (seeded) as sources; ``reference`` = the source draw (0..)."""
    machines = sorted(frame["machine"].astype(str).unique())
    if len(machines) < 2:
        raise ValueError(f"training pairs need at least two machines, got {machines}")
    rng = np.random.default_rng(seed)
    by_machine = {m: frame[frame["machine"].astype(str) == m] for m in machines}
    parts = []
    for m in machines:
        others = [o for o in machines if o != m]
        for r, src in enumerate(rng.choice(others, size=min(n_sources, len(others)), replace=False)):
            parts.append(matched_pairs(by_machine[str(src)], by_machine[m], output_group, input_groups, r))
    return concat_datasets(parts)


def machine_folds(machines: Sequence[str], k: int, seed: int = 0) -> list[tuple[list[str], list[str]]]:
    """Grouped K-fold over machines: ``k`` (train, test) splits, every machine in exactly one test fold.

    Raises:
        ValueError: ``k < 2`` or more folds than machines.
    """
    names = sorted({str(m) for m in machines})
    if not 2 <= k <= len(names):
        raise ValueError(f"need 2 <= k <= number of machines ({len(names)}), got k={k}")
    order = np.random.default_rng(seed).permutation(len(names))
    folds = [sorted(names[i] for i in order[j::k]) for j in range(k)]
    return [([n for n in names if n not in test], test) for test in folds]


def design_descriptor(spec: LoaderSpec) -> np.ndarray:
    """A machine's design as a dimensionless vector (lengths per boom length L, forces per operating weight W,
    speeds per √(gL)): the pins that may move, bucket capacity / L³, mass / L³ (kg/m³), cylinder force at relief
    / W and flow-limited speed for both circuits, traction, travel speed. Used to find a target's nearest
    calibrated machine and to score how far it lies from the machines a model was trained on."""
    from scaletwin_envs.design_space import MOVABLE_PINS
    from scaletwin_envs.specs.loader import GRAVITY

    g = spec.geometry
    L = g.boom_length
    px, pz = g.boom_pivot
    pins = [c for p in MOVABLE_PINS for c in ((getattr(g, p)[0] - px) / L, (getattr(g, p)[1] - pz) / L)]
    froude = np.sqrt(GRAVITY * L)
    return np.array([
        *pins, np.log(heaped_capacity(spec.geometry) / L**3), np.log(spec.operating_mass / L**3),
        np.log(spec.lift.max_extend_force / spec.weight), np.log(spec.tilt.max_extend_force / spec.weight),
        np.log(spec.lift.extend_speed / froude), np.log(spec.tilt.extend_speed / froude),
        spec.traction_coefficient, np.log(spec.travel_speed / froude),
    ])


def nearest_machines(target: LoaderSpec, candidates: Mapping[str, LoaderSpec], k: int = 1) -> list[str]:
    """The ``k`` candidates whose :func:`design_descriptor` is nearest to the target's (standardised over
    candidates), nearest first (ties by name)."""
    if k < 1:
        raise ValueError(f"k must be at least 1, got {k}")
    names = sorted(candidates)
    x = np.array([design_descriptor(candidates[n]) for n in names])
    sd = x.std(axis=0)
    sd[sd == 0] = 1.0
    d = np.linalg.norm((x - design_descriptor(target)) / sd, axis=1)
    return [names[i] for i in np.argsort(d, kind="stable")[:k]]


def nearest_machine(target: LoaderSpec, candidates: Mapping[str, LoaderSpec]) -> str:
    """The candidate whose :func:`design_descriptor` is nearest to the target's (:func:`nearest_machines`)."""
    return nearest_machines(target, candidates, 1)[0]


def relief_share(frame: pd.DataFrame, specs: Mapping[str, LoaderSpec], level: float = 0.98) -> pd.Series:
    """Per machine, the share of its dig-episode rows with the lift or tilt cylinder at ≥ ``level`` × its relief
    pressure: a real loader's standard dig reaches relief only in short peaks; a twin that sits there sets its pin
    forces by the relief valve rather than by the soil."""
    dig = frame[frame["kind"].astype(str) == "dig"] if "kind" in frame.columns else frame
    labels = dig["machine"].astype(str)
    relief = {n: (s.lift.relief_pressure, s.tilt.relief_pressure) for n, s in specs.items()}
    lift = labels.map({n: r[0] for n, r in relief.items()}).to_numpy(float)
    tilt = labels.map({n: r[1] for n, r in relief.items()}).to_numpy(float)
    at = ((np.abs(dig["p_lift"].to_numpy(float)) >= level * lift)
          | (np.abs(dig["p_tilt"].to_numpy(float)) >= level * tilt))
    return pd.Series(at, index=dig.index).groupby(labels).mean()
