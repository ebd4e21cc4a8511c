"""The miniature validation of the paper's section 4: the 11 kg loader at static equilibrium under known loads.

Data (independent of MuJoCo): :func:`static_rows` solves the statics of the ``"mini"`` preset analytically with
:func:`scaletwin_envs.physics.statics.solve_static` at the documented :data:`CARRY_POSE`, for loads of 0.5–4 kg
(:data:`LOADS`), the load's centre of mass being the centroid of a gravel-like fill of the bucket (the default of
``solve_static``: fill = load / rated load). It returns the Eq. (10)/(23) signals: F21, F31 (N, magnitudes on the
bucket), Pf_tilt, Pf_lift (N, axial cylinder forces), x_b, y_b (m, centre of mass of bucket + load relative to the
bucket pin O in the bucket frame), m_b (kg), and a1 = α1 = V1 = w1 = 0 (at rest). :func:`env_at_rest` settles the
simulator's MuJoCo model of the same machine at the same pose and load as a cross-check (tests require 1 %).

Prediction (δ1 convention of :mod:`scaling.dimensions.factors`): source = one reference row of the ER12 twin (the
paper's "model"), target = a miniature row (the paper's "prototype"); each model predicts δ1 = π1(source)/π1(target)
from the distortions of the miniature's groups, and F21_mini = F31_mini · π1(source) / δ1 (Eq. 22). ``direct-pi``
is δ1 ≡ 1 (direct Buckingham-Pi scaling). Errors are signed percentages ``100·(predicted − actual)/actual``.

Recurrent models see each load as a sequence of :data:`scaling.models.fitted.STATIC_STEPS` identical rows (the machine
at rest for a while) and are read at its last step.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np
import pandas as pd

from scaletwin_envs.builder import build_model
from scaletwin_envs.physics.bucket import load_centroid
from scaletwin_envs.physics.kinematics import LinkagePose, solve_pose
from scaletwin_envs.physics.mass_layout import linkage_layout
from scaletwin_envs.physics.statics import solve_static
from scaletwin_envs.runtime import qpos_for_pose, set_payload
from scaletwin_envs.signals import SignalReader
from scaletwin_envs.specs import LoaderSpec, make_loader
from scaling.data.delta_dataset import DeltaDataset
from scaling.models import DeepEnsemble, DeltaModel, DirectPi, GRUModel
from scaling.models.fitted import STATIC_STEPS, model_groups

#: Carry pose (rad): boom raised 0.35 rad above the dig pose, bucket racked back to a pitch of 0.6 rad (the
#: scripted cycle racks to 0.55); both cylinders are mid-stroke there (lift ≈ 40 %, tilt ≈ 45 % extended), so
#: the cylinders, not their end stops, hold the load, as in the static-hold training episodes.
CARRY_POSE: dict[str, float] = {"boom": 0.35, "pitch": 0.6}
#: The paper's load range: 0.5–4 kg in 8 steps.
LOADS: tuple[float, ...] = tuple(float(x) for x in np.linspace(0.5, 4.0, 8))
DIRECT_PI = "direct-pi"


def carry_pose(spec: LoaderSpec, boom: float = CARRY_POSE["boom"], pitch: float = CARRY_POSE["pitch"]) -> LinkagePose:
    """The linkage at boom angle ``boom`` and bucket pitch ``pitch`` (rad, relative to the reference pose)."""
    return solve_pose(spec.geometry, boom, pitch - boom)


def payload_com(spec: LoaderSpec, load: float) -> np.ndarray:
    """Load centre of mass relative to O in the bucket frame (m): a gravel-like fill of ``load / rated_load``."""
    fill = min(load / max(spec.rated_load, 1e-12), 1.0)
    return load_centroid(spec.geometry, fill) - np.asarray(spec.geometry.pin_O)


def static_rows(spec: str | LoaderSpec = "mini", loads: tuple[float, ...] = LOADS, boom: float = CARRY_POSE["boom"],
                pitch: float = CARRY_POSE["pitch"]) -> pd.DataFrame:
    """One analytical static-equilibrium row per load (kg); columns as the recordings (SI: signals, cylinder
    extensions from fully retracted, ``m_load``, ``kind = "hold"``) plus ``load_kg``."""
    loader = make_loader(spec)
    pose = carry_pose(loader, boom, pitch)
    bucket = linkage_layout(loader)["bucket"]
    rows = []
    for i, load in enumerate(loads):
        com = payload_com(loader, load)
        sol = solve_static(loader, pose, payload_mass=load, payload_com_local=com)
        m_b = bucket.mass + load
        x_b, y_b = (bucket.mass * bucket.com + load * com) / m_b  # bucket frame, relative to O
        rows.append({"machine": loader.name, "episode": i, "t": 0.0, "load_kg": float(load), "F21": sol.F21,
                     "F31": sol.F31, "Pf_tilt": sol.Pf_tilt, "Pf_lift": sol.Pf_lift, "x_b": float(x_b),
                     "y_b": float(y_b), "m_b": m_b, "a1": 0.0, "alpha1": 0.0, "V1": 0.0, "w1": 0.0,
                     "boom_angle": pose.boom, "bucket_pitch": pose.bucket_pitch, "m_load": float(load), "kind": "hold",
                     "lift_extension": pose.lift_length - loader.lift.closed_length,
                     "tilt_extension": pose.tilt_length - loader.tilt.closed_length})
    return pd.DataFrame(rows)


def env_at_rest(spec: str | LoaderSpec, load: float, boom: float = CARRY_POSE["boom"],
                pitch: float = CARRY_POSE["pitch"], settle_froude: float = 15.0) -> dict[str, float]:
    """Signals of the simulator's MuJoCo model of ``spec`` settled at the pose with ``load`` kg in the bucket.

    The model is built by :func:`scaletwin_envs.builder.build_model` (as the env builds it), held with zero cylinder
    speed for ``settle_froude`` Froude times, and read by the env's :class:`~scaletwin_envs.signals.SignalReader`.
    """
    loader = make_loader(spec)
    model = build_model(loader)
    data = mujoco.MjData(model)
    data.qpos[:] = qpos_for_pose(model, loader, carry_pose(loader, boom, pitch))
    set_payload(model, data, load, payload_com(loader, load), 0.1 * loader.characteristic_length)
    mujoco.mj_step(model, data, int(settle_froude * loader.froude_time / model.opt.timestep))
    mujoco.mj_forward(model, data)
    mujoco.mj_rnePostConstraint(model, data)
    areas = {k: (getattr(loader, k).bore_area, getattr(loader, k).annulus_area) for k in ("lift", "tilt")}
    return SignalReader(model, areas, loader.weight).read(data, np.zeros(2), two_routes=False)


def static_pairs(model: DeltaModel, reference: pd.Series, rows: pd.DataFrame) -> tuple[DeltaDataset, np.ndarray]:
    """(pairs, index of the row each prediction belongs to) for ``model``: one pair per row, or the last step of
    a constant :data:`~scaling.models.fitted.STATIC_STEPS` sequence per row for recurrent models."""
    output, inputs = model_groups(model)
    if not isinstance(model, GRUModel):
        return DeltaDataset.from_pairs(reference, rows, output, inputs, warn=False), np.arange(len(rows))
    seq = rows.loc[rows.index.repeat(STATIC_STEPS)].reset_index(drop=True)
    seq["episode"] = np.repeat(np.arange(len(rows)), STATIC_STEPS)
    seq["t"] = np.tile(np.arange(STATIC_STEPS, dtype=float), len(rows))
    last = np.arange(len(rows)) * STATIC_STEPS + STATIC_STEPS - 1
    return DeltaDataset.from_pairs(reference, seq, output, inputs, warn=False), last


@dataclass
class MiniValidation:
    """Predicted against analytical F21 on the miniature per model (N), and signed percentage errors."""

    loads_kg: np.ndarray
    actual: np.ndarray
    predicted: dict[str, np.ndarray] = field(default_factory=dict)
    intervals: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    reference: dict[str, Any] = field(default_factory=dict)

    def pct_error(self, name: str) -> np.ndarray:
        return 100.0 * (self.predicted[name] - self.actual) / self.actual

    def mean_abs(self, name: str) -> float:
        return float(np.mean(np.abs(self.pct_error(name))))

    def reduction(self, name: str, baseline: str = DIRECT_PI) -> float:
        """Fraction of the baseline's mean absolute error removed by ``name`` (0.9 = 90 % less error)."""
        return 1.0 - self.mean_abs(name) / self.mean_abs(baseline)

    def to_json(self) -> dict[str, Any]:
        """``{"loads_kg": [...], "models": {NAME: {"mean_abs_pct_error": x, "pct_error": [...]}}}``."""
        return {"loads_kg": [float(x) for x in self.loads_kg],
                "models": {n: {"mean_abs_pct_error": self.mean_abs(n),
                               "pct_error": [float(x) for x in self.pct_error(n)]} for n in self.predicted}}

    def table(self) -> pd.DataFrame:
        """One row per load: actual F21 and each model's prediction (N) and error (%)."""
        out = pd.DataFrame({"load_kg": self.loads_kg, "F21_actual_N": self.actual})
        for n in self.predicted:
            out[f"{n} F21 (N)"] = self.predicted[n]
            out[f"{n} error (%)"] = self.pct_error(n)
        return out

    def coverage(self, name: str) -> float:
        lo, hi = self.intervals[name]
        return float(np.mean((self.actual >= lo) & (self.actual <= hi)))

    def abs_pct_errors(self) -> dict[str, np.ndarray]:
        """|100·(predicted − actual)/actual| per model and load (%), what Fig. 12 plots
        (:func:`scaling.runs.plots.plot_mini_validation`)."""
        return {n: np.abs(self.pct_error(n)) for n in self.predicted}


def validate_mini(models: Mapping[str, DeltaModel], reference: pd.Series, rows: pd.DataFrame | None = None,
                  coverage: float = 0.9) -> MiniValidation:
    """Predict F21 on the static miniature rows with every model (plus ``direct-pi`` if absent).

    Args:
        models: fitted δ1 models by name.
        reference: the source row (ER12, all signals); the paper's "model" row.
        rows: target rows (default :func:`static_rows`); need ``load_kg`` and the signals of each model's groups.
        coverage: interval level for models with intervals (:class:`~scaling.models.DeepEnsemble`).
    """
    rows = static_rows() if rows is None else rows.reset_index(drop=True)
    result = MiniValidation(rows["load_kg"].to_numpy(float), rows["F21"].to_numpy(float),
                            reference={k: _jsonable(v) for k, v in reference.items()})
    fitted = dict(models)
    if DIRECT_PI not in fitted and fitted:
        first = next(iter(fitted.values()))
        direct = DirectPi()
        direct.transform_, direct.groups_ = first.transform_, first.groups_
        fitted[DIRECT_PI] = direct
    for name, model in fitted.items():
        pairs, pick = static_pairs(model, reference, rows)
        result.predicted[name] = model.predict_target(pairs)[pick]
        if isinstance(model, DeepEnsemble):
            lo, hi = model.predict_target_interval(pairs, coverage)
            result.intervals[name] = (lo[pick], hi[pick])
    return result


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    return value
