"""The product-line δ1 checkpoint ``statics-pl``: F21 of a machine of *another design*, from any calibrated one.

The paper's checkpoints (:mod:`zoo.build`) learnt δ1 on two machines only, the ER12 and the WA475. This one is
trained across a sampled product line (:class:`scaling.evaluation.generalisation.LeaveMachineOut`: the ER12 and 24 drawn
machines that differ in linkage, hydraulics, masses, bucket and traction), on matched (source, target) row pairs,
so any calibrated machine of the line can be the source. Its output group is π1 = F21 / F21_linkage (F21 over the
pin force of the massless linkage at the measured tilt-cylinder force and pose), its inputs the Eq. (10) groups,
the pose and the linkage's design signals (:func:`scaling.data.product_line.add_design_signals`), source and target
values both.

Its card says what the leave-machine-out proof measured: per held-out machine (drawn with another seed, never
used in training or calibration, plus the ``mini`` and ``wa475`` presets) the F21 error on dig and hold rows,
the peak error and the coverage of the card's interval. The interval is calibrated on 40 calibration machines
(held out of training) for "a new machine of the line", not for rows of machines the model saw: per row, ln δ1 ±
q·s(x) with a width s learnt from what the served model knows of the row and q covering 90 % of the rows of the
median calibration machine (:class:`scaling.evaluation.conformal.RowInterval`; the bound chosen leaving each
calibration machine out in turn, :func:`scaling.evaluation.generalisation.cross_fit_served`, whose figures the card
carries as ``metrics.calibration_cross_fit``); row by row (no novelty query) the pooled group-weighted residual
quantiles. It also serves per row the risk that F21 is more than 10 % off, read off that interval
(:class:`scaling.evaluation.conformal.RowRisk`, ``ScaledForce.risk``), and warns where it is at least one half: its
warnings replace the training-range rule, which fired on a quarter of a new machine's rows at 0.5 % error.

How to use it: compute the design signals of both machines from their specs, pair every target row with its
matched source row (:func:`scaling.data.product_line.match_rows`: same kind, nearest in pose and fill) and pass the
paired rows (``model.scale_force(source.iloc[idx], target)``); see ``examples/scale_product_line.py``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from scaletwin_envs.signal_units import QUANTITY_UNITS
from scaling.data.product_line import PI1_LINKAGE
from scaling.data.recordings import dataset_hash
from scaling.evaluation.conformal import group_weighted_quantile
from scaling.evaluation.generalisation import (
    PRODUCT_LINE_NET,
    Candidate,
    GeneralisationResult,
    LeaveMachineOut,
    cross_fit_served,
    evaluate,
    finite_groups,
    judged_rows,
    linkage_input_groups,
)
from scaling.evaluation.metrics import at_rest
from scaling.models import FFNN, DeepEnsemble, DeltaModel
from scaling.models.fitted import model_groups
from scaling.runs.provenance import code_version, machine, to_jsonable
from scaling.runs.provenance import versions as scaling_versions
from zoo.build import COVERAGES, RANGE_MARGIN
from zoo.registry import REGISTRY_PATH, ZOO_ROOT, register
from zoo.scaling_kind import save_scaling_model
from zoo.serving.model import served_variables

NAME = "statics-pl"
SUMMARY = ("δ1 FFNN across a sampled product line (linkage, hydraulics, masses, bucket, traction differ), π1 = "
           "F21/F21_linkage, matched source rows: F21 of a machine of another design from any calibrated one; "
           "interval calibrated on held-out machines.")
#: The product-line deep ensemble: the same inputs and output, three members, served from three sources.
ENSEMBLE_NAME = "statics-pl-ens"
ENSEMBLE_SUMMARY = ("δ1 deep ensemble (3 members) across a sampled product line, π1 = F21/F21_linkage, matched "
                    "source rows; from one calibrated machine or, best, three (geometric mean, interval calibrated "
                    "for three sources on held-out machines).")
DELTA_CONVENTION = ("source = a calibrated machine of the product line, one matched row per target row (same kind, "
                    "nearest in boom angle, bucket pitch and fill: scaling.data.product_line.match_rows); target = the "
                    "machine to predict; δ1 = π1(source)/π1(target), π1 = F21/F21_linkage, and F21_target = "
                    "F21_linkage_target · π1(source) / δ1. F21_linkage = tilt_ratio · |Pf_tilt| follows from the "
                    "target's drawing, pose and tilt-cylinder force (scaling.data.product_line.add_design_signals).")


@dataclass(frozen=True)
class ProductLineBuild:
    """What :func:`build_product_line` builds; ``data_dir`` holds ``train/`` and ``test/`` recordings (simulated
    there when missing, resumable). The ``check`` machine's first dig cycle becomes the checkpoint's check set."""

    data_dir: Path = Path("runs/zoo-product-line")
    layout: LeaveMachineOut = field(default_factory=LeaveMachineOut)
    seed: int = 0
    coverage: float = 0.9
    check: str = "pl1-0"
    out_root: Path = ZOO_ROOT / "checkpoints"
    registry: Path = REGISTRY_PATH
    executor: str | int | None = 2
    progress: bool = True
    net: dict[str, Any] = field(default_factory=lambda: dict(PRODUCT_LINE_NET))
    #: checkpoint name and registry summary
    name: str = NAME
    summary: str = SUMMARY
    #: members of a deep ensemble; 0: one FFNN
    ensemble: int = 0
    #: source machines the card's second interval and error score are calibrated for (each target row predicted
    #: from the matched rows of that many calibrated machines, geometric mean: ``ScalingModel.scale_force_sources``);
    #: 1: none
    sources: int = 3

    def build_model(self) -> DeltaModel:
        """The unfitted δ1 model of this checkpoint."""
        if self.ensemble:
            return DeepEnsemble(k=self.ensemble, **self.net, seed=self.seed, include_source=True)
        return FFNN(**self.net, seed=self.seed, include_source=True)

    @property
    def multi_name(self) -> str:
        """The name the leave-machine-out judge gives the model judged from :attr:`sources` sources."""
        return f"{self.name}, {self.sources} sources"


def ensemble_build(**changes: Any) -> ProductLineBuild:
    """The build of :data:`ENSEMBLE_NAME` (``changes`` as for :class:`ProductLineBuild`)."""
    return ProductLineBuild(**{"name": ENSEMBLE_NAME, "summary": ENSEMBLE_SUMMARY, "ensemble": 3, **changes})


def build_product_line(cfg: ProductLineBuild | None = None) -> Path:
    """Simulate/load the line, fit, judge on held-out machines (from one source, and from :attr:`~ProductLineBuild.
    sources` sources), write and register the checkpoint (``statics-pl`` by default); its directory."""
    cfg = cfg or ProductLineBuild()
    if cfg.sources < 1:
        raise ValueError(f"sources must be at least 1, got {cfg.sources}")
    say = print if cfg.progress else (lambda _msg: None)
    start = time.perf_counter()
    frame = cfg.layout.load(cfg.data_dir, cfg.executor, cfg.progress)
    split = cfg.layout.split()
    if cfg.sources > len(split.train):
        raise ValueError(f"sources={cfg.sources} but the layout trains on {len(split.train)} machines")
    groups = linkage_input_groups(frame[frame["machine"].isin(split.train)])
    candidates = [Candidate(cfg.name, cfg.build_model, groups, PI1_LINKAGE)]
    if cfg.sources > 1:
        candidates.append(Candidate(cfg.multi_name, cfg.build_model, groups, PI1_LINKAGE, sources=cfg.sources,
                                    same_model_as=cfg.name))
    result = evaluate(frame, split, candidates, seed=cfg.seed, progress=say)
    model = result.models[cfg.name]
    by_machine = {str(m): g.reset_index(drop=True) for m, g in frame.groupby(frame["machine"].astype(str))}
    reference = reference_row(by_machine[split.reference], groups)
    check = check_rows(by_machine[cfg.check], groups)
    fields = card_fields(model, result, reference, check, frame, cfg)
    fields["training"]["build_s"] = time.perf_counter() - start
    path = save_scaling_model(model, Path(cfg.out_root) / cfg.name, to_jsonable(fields), check, overwrite=True,
                              risk=result.row_risk[cfg.name])
    register(cfg.name, path, cfg.summary, cfg.registry)
    return path


def reference_row(source: pd.DataFrame, groups: tuple[Any, ...]) -> pd.Series:
    """The card's default source: the source machine's judged hold row at rest with the median fill (SI)."""
    rows = source[judged_rows(source) & at_rest(source)]
    finite = finite_groups(rows, (*groups, PI1_LINKAGE))
    rows = rows[finite]
    if rows.empty:
        raise ValueError("the reference machine has no judged rows at rest with finite groups")
    return rows.iloc[int(np.argsort(rows["fill"].to_numpy(float))[len(rows) // 2])]


def check_rows(target: pd.DataFrame, groups: tuple[Any, ...]) -> pd.DataFrame:
    """The check set: the first dig cycle of the check machine (judged rows with finite groups), with the target
    quantities the model serves (SI); its source is the card's reference row."""
    digs = target[(target["kind"] == "dig") & judged_rows(target)]
    rows = digs[digs["episode"] == digs["episode"].min()]
    finite = finite_groups(rows, (*groups, PI1_LINKAGE))
    _, target_vars = served_variables(PI1_LINKAGE, groups, "F21")
    return rows[finite][["machine", "episode", "t", *target_vars]].reset_index(drop=True)


def held_out_metrics(result: GeneralisationResult, name: str, presets: tuple[str, ...]
                     ) -> tuple[dict[str, dict[str, Any]], dict[str, Any]]:
    """(per held-out machine, summary over the drawn ones, ``presets`` left out) of the judged model ``name``: F21
    errors, the served interval's coverage, the served error score's warnings, matched direct-Pi beside them.

    Where no risk was calibrated (``result.extrapolation["row_risk_unavailable"]``), the risk figures are None and
    the summary's ``risk_unavailable`` says why; otherwise ``risk_unavailable`` is None."""
    table = result.frame()
    ours = table[table["model"] == name].set_index("machine")
    base = table[table["model"] == "direct-Pi (nearest machine)"].set_index("machine")
    unavailable = risk_unavailable(result, name)
    warned, false_alarms = ({} if unavailable else result.extrapolation[k][name]
                            for k in ("row_risk_warn_share", "row_risk_false_alarms"))
    per_machine = {m: {"source": r.source, "dynamic_mape_pct": r.dynamic_mape, "static_mape_pct": r.static_mape,
                       "peak_error_pct": r.peak_error, "interval_coverage": r.coverage_served,
                       "pooled_interval_coverage": r.coverage_spread, "rows": r.rows,
                       "rows_over_10pct": r.miss_share,
                       "direct_pi_dynamic_mape_pct": float(base.loc[m, "dynamic_mape"]),
                       "direct_pi_static_mape_pct": float(base.loc[m, "static_mape"]),
                       "risk_warned_share": warned.get(m), "risk_false_alarms": false_alarms.get(m)}
                   for m, r in ours.iterrows()}
    drawn = ours.drop(index=list(presets), errors="ignore")
    summary = {"drawn_test_machines": len(drawn),
               "dynamic_mape_pct_median": float(drawn["dynamic_mape"].median()),
               "dynamic_mape_pct_worst": float(drawn["dynamic_mape"].max()),
               "static_mape_pct_median": float(drawn["static_mape"].median()),
               "static_mape_pct_worst": float(drawn["static_mape"].max()),
               "interval_coverage_min": float(drawn["coverage_served"].min()),
               "interval_coverage_max": float(drawn["coverage_served"].max()),
               "interval_machines_85_95": int(drawn["coverage_served"].between(0.85, 0.95).sum()),
               "risk_auroc": None if unavailable else result.extrapolation["auroc_row_risk"][name],
               "risk_auroc_at": None if unavailable else result.extrapolation["auroc_row_risk_at"][name],
               "risk_warned_share_max": None if unavailable else float(np.max([warned[m] for m in drawn.index])),
               "risk_warned_share_median": None if unavailable else float(np.median([warned[m] for m in drawn.index])),
               "risk_false_alarms_median": (None if unavailable
                                            else float(np.median([false_alarms[m] for m in drawn.index]))),
               "risk_unavailable": unavailable}
    return per_machine, summary


def calibration_cross_fit(result: GeneralisationResult, name: str) -> dict[str, Any] | None:
    """The served interval and error score of the judged model ``name`` on the calibration machines, each left out
    in turn (:meth:`scaling.evaluation.generalisation.CrossFit.summary`); None with fewer than three calibration
    machines (nothing to leave out and still cross-fit)."""
    rows = result.calibration_rows[name]
    return cross_fit_served(rows).summary() if rows["machine"].nunique() >= 3 else None


def risk_unavailable(result: GeneralisationResult, name: str) -> str | None:
    """Why the judged model ``name`` has no served risk (None: it has one)."""
    risk = result.row_risk.get(name)
    if risk is None:
        return "no error score was fitted for this model"
    return risk.unavailable if risk.score is None else None


def card_fields(model: DeltaModel, result: GeneralisationResult, reference: pd.Series, check: pd.DataFrame,
                frame: pd.DataFrame, cfg: ProductLineBuild) -> dict[str, Any]:
    """Everything the card says (see :mod:`zoo.scaling_kind`)."""
    assert model.groups_ is not None
    name = cfg.name
    inputs = tuple(model_groups(model)[1])
    source_vars, target_vars = served_variables(PI1_LINKAGE, inputs, "F21")
    residual, machines = result.calibration[name]
    quantiles = {str(c): [-group_weighted_quantile(-residual, machines, (1 + c) / 2),
                          group_weighted_quantile(residual, machines, (1 + c) / 2)] for c in COVERAGES}
    lo, hi = result.training_range[name]
    per_machine, summary = held_out_metrics(result, name, cfg.layout.test_presets)
    split = cfg.layout.split()
    multi: dict[str, Any] = {}
    if cfg.sources > 1:
        per_k, summary_k = held_out_metrics(result, cfg.multi_name, cfg.layout.test_presets)
        multi = {"interval": {"sources": cfg.sources, "learned_scale": result.row_interval[cfg.multi_name].state(),
                              "risk": (None if (multi_score := result.row_risk[cfg.multi_name].score) is None
                                       else multi_score.state()),
                              "risk_unavailable": risk_unavailable(result, cfg.multi_name),
                              "description": f"from {cfg.sources} sources (ScalingModel.scale_force_sources): the "
                                             "geometric mean of the F21 each source gives; its ln δ1 (that of the "
                                             "first source which recovers the mean) ± q·s(x) and the risk read off it "
                                             "calibrated on the calibration machines, each predicted from its "
                                             f"{cfg.sources} nearest training machines"},
                 "metrics": {"held_out_machines": per_k, "summary": summary_k}}
    interval = {"method": "learned-scale", "coverage": cfg.coverage,
                "learned_scale": result.row_interval[name].state(),
                "log_delta_residual_quantiles": quantiles,
                "calibration": f"ln δ1 residuals on the {len(split.calibration)} calibration machines "
                               "(held out of training). learned_scale (batch path, risk computed): "
                               "ln δ1 ± q·s(x), s learnt from the served features "
                               "(scaling.evaluation.conformal.RowInterval, cross-fitted over the calibration "
                               "machines), q covering the coverage share of the rows of machine_share of the "
                               "calibration machines (scaling.evaluation.conformal.machine_level_quantile). "
                               "log_delta_residual_quantiles (row by row, or risk=False): every machine "
                               "weighing the same, pooled (scaling.evaluation.conformal.group_weighted_quantile)",
                "description": "δ1·exp(±q·s) or δ1·exp(q) for the residual quantiles q, mapped to F21 "
                               "(bounds swap)"}
    if multi:
        interval["multi_source"] = multi["interval"]
    return {
        "name": name,
        "description": cfg.summary,
        "predicts": {"variable": "F21", "unit": "N",
                     "quantity": "F21: magnitude of the force on the bucket at its pin to link B (N)",
                     "model_output": "δ1 = π1(source)/π1(target), π1 = F21/F21_linkage",
                     "equation": "F21_target = F21_linkage_target · π1(source) / δ1"},
        "delta_convention": DELTA_CONVENTION,
        "groups": {"set": "eq10+pose+linkage", **model.groups_},
        "source": {"machine": split.reference, "index": int(reference.name),
                   "selection": "the ER12's hold row at rest with the median fill (zoo.product_line.reference_row); "
                                "a default only: pass matched rows of your calibrated machine",
                   "row": {k: float(reference[k]) for k in source_vars},
                   "variables": source_vars, "units": {k: QUANTITY_UNITS[k] for k in source_vars}},
        "inputs": [{"name": k, "unit": QUANTITY_UNITS[k]} for k in target_vars],
        "interval": interval,
        "training_range": {"feature": "g_n = s_n·[asinh(π_n^s/2ε_n) − asinh(π_n^t/2ε_n)], then s_n·asinh(π_n^s/2ε_n) "
                                      "(include_source), on the training pairs",
                           "groups": [g.expression() for g in inputs], "min": lo, "max": hi, "margin": RANGE_MARGIN,
                           "rule": "a target row is extrapolated when any feature lies outside [min − margin·span, "
                                   "max + margin·span], span = max − min"},
        "training": {"layout": cfg.layout.to_dict(), "machines": list(split.train),
                     "calibration_machines": list(split.calibration), "units": "SI (N, m, kg, s, rad)",
                     "data_hash": dataset_hash(frame.drop(columns=["episode_key"])),
                     "model": {"class": type(model).__name__, "config": model.get_config()}, "seed": cfg.seed,
                     "fit_s": result.fit_seconds[name], "code_version": code_version(),
                     "command": "scaletwin zoo build --product-line (zoo.product_line.build_product_line)",
                     "machine": machine(), "package_versions": scaling_versions()},
        "metrics": {
            "held_out_machines": per_machine,
            "summary": summary,
            **({"multi_source": {"sources": cfg.sources, **multi["metrics"]}} if multi else {}),
            "risk_unavailable": summary["risk_unavailable"],
            "calibration_cross_fit": calibration_cross_fit(result, name),
            **({"calibration_cross_fit_multi_source": calibration_cross_fit(result, cfg.multi_name)}
               if multi else {}),
            "calibration_cross_fit_note": "the served interval (every bound compared), its risk and the logistic "
                                          "error scores compared with it fitted on all calibration machines but one "
                                          "and judged on it, each in turn (scaling.evaluation.generalisation."
                                          "cross_fit_served); where the served bound and threshold were chosen",
            "risk_note": "served per row (ScaledForce.risk): P(F21 more than 10 % off), read off the served "
                         "interval (scaling.evaluation.conformal.IntervalRisk): the share of the median calibration "
                         "machine's rows whose residual over its width exceeds the miss line over this row's width "
                         "(a power-law tail beyond the 99 % bound); it warns where that is at least 0.5. "
                         "risk_auroc: how well it separates the held-out machines' rows more than 10 % off (0.5 = "
                         "chance); risk_auroc_at: the same for rows more than 3 % and 5 % off; false alarms: the "
                         "share of rows at most 10 % off that it warns on. Where a card has no risk, "
                         "risk_unavailable says why, the risk figures are null, ScaledForce.risk is None and the "
                         "served model says so (ScalingModel.risk_unavailable); the interval is served as usual",
            "note": "machines never trained on nor used for calibration (drawn with another seed, plus the mini and "
                    "wa475 presets); rows after start-up settling with F21 > 5 % of the machine's peak; dynamic = "
                    "dig cycles and moves, static = bucket held still; source = the nearest training machine by "
                    "design, matched rows (scaling.evaluation.generalisation)",
            "check_set": {"file": "check.csv", "rows": len(check), "machine": cfg.check},
        },
    }
