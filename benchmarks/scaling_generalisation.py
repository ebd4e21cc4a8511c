"""Leave-machine-out benchmark: δ1 models judged on machines of the product line they never saw.

Machines: 64 drawn from the design space with seed 0 plus the ER12 preset; 24 of the drawn ones and the ER12
train, the other 40 calibrate the conformal intervals, the error score and the extrapolation threshold (16 until
2026-11-28: too few, see ``benchmarks/interval_limits.py``).
Test: 10 machines drawn with seed 1 (never used for anything else), the ``mini`` preset (simulated dig cycles
and holds: the miniature) and the ``wa475`` preset. Every machine digs 4 soils × 2 pile heights and does 4
static-hold episodes. Per test machine: F21 MAPE and median error on dig rows and on holds (rows after start-up
settling with F21 > 5 % of the machine's peak), peak F21 error, 90 % interval coverage, the share of rows the error
score warns on; over all test rows, the AUROC of the error score and of the design distance.

Before the test machines, the served interval and error score are judged on the 40 calibration machines, each left
out in turn (:func:`scaling.evaluation.generalisation.cross_fit_served`): where their bound and threshold were chosen.

Run: ``python benchmarks/scaling_generalisation.py [--data DIR] [--workers 2] [--quick]``; recordings are kept
in ``--data`` (resumable: an interrupted run re-simulates only what is missing), results go to
``benchmarks/results/scaling_generalisation.{md,csv,json}``. ``--test-seed 13 --test-data DIR --out
benchmarks/results/scaling_generalisation_seed13`` judges the same fitted models on a fresh test line drawn with
seed 13 (its recordings in ``--test-data``).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from scaletwin_envs.host import host_line
from scaling.data.product_line import LINKAGE_GROUPS, PI1_LINKAGE, relief_share
from scaling.data.recordings import dataset_hash
from scaling.dimensions.group_choice import POSE_GROUPS
from scaling.evaluation.generalisation import (
    PRODUCT_LINE_NET,
    Candidate,
    LeaveMachineOut,
    cross_fit_served,
    evaluate,
    linkage_input_groups,
)
from scaling.models import FFNN, DeepEnsemble
from scaling.runs.provenance import code_version, versions

#: The judged models a checkpoint serves (``statics-pl``, ``statics-pl-ens`` from one and three sources): their
#: interval and error score are also judged on the calibration machines, each left out in turn.
SERVED = ("ffnn-statics (pairs, π1 = F21/F21_linkage)", "ensemble-statics (pairs, π1 = F21/F21_linkage)",
          "ensemble-statics, 3 nearest sources")
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(tempfile.gettempdir()) / "scaletwin-bench-product-line")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="8+4 machines, 2 soils: a smoke run (minutes)")
    ap.add_argument("--test-seed", type=int, default=1, help="design-space seed of the test machines (default 1)")
    ap.add_argument("--test-data", type=Path, default=None,
                    help="recordings of the test line (default DATA/test; give another folder with --test-seed)")
    ap.add_argument("--out", default="benchmarks/results/scaling_generalisation")
    ap.add_argument("--render", action="store_true", help="rewrite the Markdown from the CSV and JSON of --out")
    args = ap.parse_args()
    if args.render:
        out = Path(args.out)
        text = report(pd.read_csv(out.with_suffix(".csv")), json.loads(out.with_suffix(".json").read_text()))
        out.with_suffix(".md").write_text(text)
        print(text)
        return
    torch.set_num_threads(1)
    load = [os.getloadavg()[0]]
    started = time.perf_counter()
    layout = (LeaveMachineOut(n_train=6, n_calibration=3, n_test=3, soils=("gravel", "clay_loam"),
                              test_seed=args.test_seed) if args.quick else LeaveMachineOut(test_seed=args.test_seed))
    if args.test_seed != 1 and args.test_data is None:
        ap.error("--test-seed needs --test-data (the default test folder holds the seed-1 line)")
    train_line, test_line = layout.lines()
    print(f"simulating or loading {len(train_line.dataset_spec().tasks()) + len(test_line.dataset_spec().tasks())} "
          f"episodes in {args.data}")
    frame = layout.load(args.data, args.workers, test_dir=args.test_data)
    load.append(os.getloadavg()[0])
    split = layout.split()
    train_frame = frame[frame["machine"].isin(split.train)]
    linkage = linkage_input_groups(train_frame)
    eq10 = linkage[: -len(POSE_GROUPS) - len(LINKAGE_GROUPS)]
    net = PRODUCT_LINE_NET
    candidates = [
        Candidate("ffnn-eq10 (pairs)", lambda: FFNN(**net, include_source=True), eq10),
        Candidate("ffnn-linkage (pairs)", lambda: FFNN(**net, include_source=True), linkage),
        Candidate("ensemble-linkage (pairs)", lambda: DeepEnsemble(k=3, **net, include_source=True), linkage),
        Candidate("ffnn-statics (pairs, π1 = F21/F21_linkage)", lambda: FFNN(**net, include_source=True), linkage,
                  PI1_LINKAGE),
        Candidate("ensemble-statics (pairs, π1 = F21/F21_linkage)",
                  lambda: DeepEnsemble(k=3, **net, include_source=True), linkage, PI1_LINKAGE),
        Candidate("ffnn-statics, 3 nearest sources", lambda: FFNN(**net, include_source=True), linkage,
                  PI1_LINKAGE, sources=3, same_model_as="ffnn-statics (pairs, π1 = F21/F21_linkage)"),
        Candidate("ensemble-statics, 3 nearest sources", lambda: DeepEnsemble(k=3, **net, include_source=True),
                  linkage, PI1_LINKAGE, sources=3,
                  same_model_as="ensemble-statics (pairs, π1 = F21/F21_linkage)"),
    ]
    result = evaluate(frame, split, candidates, progress=print)
    cross_fit = {name: cross_fit_served(rows).summary() for name, rows in result.calibration_rows.items()
                 if name in SERVED}
    load.append(os.getloadavg()[0])
    table = result.frame()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(out.with_suffix(".csv"), index=False, float_format="%.4g")
    meta = {"date": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"), "code": code_version(),
            "host": host_line(), "load_avg": load, "seconds": time.perf_counter() - started,
            "versions": versions(), **layout.to_dict(),
            "groups": {"eq10": [g.expression() for g in eq10], "linkage": [g.expression() for g in linkage]},
            "data_hash": dataset_hash(frame.drop(columns=["episode_key"])), "fit_seconds": result.fit_seconds,
            "extrapolation": result.extrapolation, "quick": args.quick, "test_seed": args.test_seed,
            "cross_fit": cross_fit,
            "relief_share": relief_share(frame, split.specs).round(3).to_dict()}
    out.with_suffix(".json").write_text(json.dumps(meta, indent=1, default=str))
    text = report(pd.read_csv(out.with_suffix(".csv")), meta)  # from the file, so that --render gives the same
    out.with_suffix(".md").write_text(text)
    print(text)


def cross_fit_lines(cross_fit: dict[str, dict]) -> list[str]:
    """The Markdown section on the served interval and error score judged on the calibration machines, each left
    out in turn (empty for results written before it existed)."""
    if not cross_fit:
        return []
    lines = ["## On the calibration machines, each left out in turn", "",
             "Where the served interval's bound and the warning threshold were chosen, without the test machines "
             "(`scaling.evaluation.generalisation.cross_fit_served`): for each of the calibration machines, the "
             "interval and its risk are fitted on the others and judged on it. Bounds: 90 % of the rows of "
             "the median calibration machine (served), of 90 % of them (before), of an average machine (pooled); "
             "'floor k': the width √(s(x)² + σ0²) with a floor σ0 = k × the median scale shared by every row "
             "(a machine-level error part). Warnings: the served one (the interval's risk of a miss of more "
             "than 10 %, at 0.5 or above) and logistic error scores on the served features (the served "
             "warning before).", "",
             "| model | bound | 90 % coverage min–max | median | machines in 85–95 % |", "|---|---|---|---|---|"]
    for name, cf in cross_fit.items():
        for label, c in cf["coverage"].items():
            lines.append(f"| {name} | {label} | {c['min']:.2f}–{c['max']:.2f} | {c['median']:.2f} | "
                         f"{c['in_band']} of {c['machines']} |")
    lines += ["", "| model | warning | rows warned on, median / max | machines above 5 % | "
              "served-risk AUROC, rows > 3 / 5 / 10 % off (rows) [logistic error score] |",
              "|---|---|---|---|---|"]
    for name, cf in cross_fit.items():
        auc = " / ".join(f"{cf['auroc'][k]:.2f} ({cf['rows_over'][k]})" for k in cf["auroc"])
        if cf.get("auroc_logistic"):
            auc += " [" + " / ".join(f"{v:.2f}" for v in cf["auroc_logistic"].values()) + "]"
        for label, w in cf["warned"].items():
            lines.append(f"| {name} | {label} | {100 * w['median']:.1f} % / {100 * w['max']:.1f} % | "
                         f"{w['above_5pct']} | {auc} |")
    return [*lines, ""]


def report(table: pd.DataFrame, meta: dict) -> str:
    """The Markdown results: summary per model over the drawn test machines, then every machine."""
    drawn = table[~table["machine"].isin(["mini", "wa475"])]
    lines = [
        "# Scaling to unseen machines (leave-machine-out)", "",
        f"{meta['date']}, code {meta['code']}, {meta['host']}, load average "
        f"{', '.join(f'{x:.1f}' for x in meta['load_avg'])}, "
        f"{meta['seconds']:.0f} s in all{' (quick smoke run)' if meta['quick'] else ''}. Produced by "
        "`python benchmarks/scaling_generalisation.py`.", "",
        f"Train: {len(meta['split']['train'])} machines (ER12 + drawn, seed 0); calibration: "
        f"{len(meta['split']['calibration'])} drawn machines; test: {len(meta['split']['test']) - 2} drawn machines "
        f"(seed {meta.get('test_seed', 1)}) + `mini` + `wa475`. Rows judged: after start-up settling, F21 > 5 % of "
        "the machine's peak; static "
        "= inertial groups below 0.1 % of F31 (the bucket held still), dynamic = the rest. "
        "Source of every target: its nearest training machine by design (direct-Pi (ER12): the ER12); the "
        "\"3 nearest sources\" rows judge the same fitted network from the 3 nearest training machines and take the "
        "geometric mean of the 3 forces (`scaling.evaluation.generalisation.combine_sources`). "
        "Intervals: split conformal over the calibration machines (each weighing the same) on a per-row scale, "
        "either learned from the error score's features (cross-fitted over the calibration machines, "
        "`scaling.evaluation.conformal.ResidualScale`) or the model's own spread (an ensemble's σ, 1 for a point "
        "model); both take the pooled quantile (90 % of the rows of an average machine). Served: the interval a "
        "checkpoint such as `statics-pl` gives (`scaling.evaluation.conformal.RowInterval`): a scale learned from "
        "what a served model knows (novelty of its feature row, |ln δ1|, bucket at rest) and a machine-level bound, "
        "90 % of the rows of the median calibration machine "
        "(`scaling.evaluation.conformal.machine_level_quantile`; chosen on the calibration machines, below).", "",
        *cross_fit_lines(meta.get("cross_fit", {})),
        "## Over the drawn test machines", "",
        "| model | dynamic rows: MAPE median / worst [%] | static rows: MAPE median / worst [%] | "
        "peak F21 error median [%] | "
        "90 % coverage min–max: learned scale / own spread / served | machines covered 85–95 % (served) | "
        "beats nearest-machine direct-Pi on |",
        "|---|---|---|---|---|---|---|",
    ]
    base = drawn[drawn["model"] == "direct-Pi (nearest machine)"].set_index("machine")
    for model, g in drawn.groupby("model", sort=False):
        g = g.set_index("machine")
        both = (g["dynamic_mape"] + g["static_mape"]) / 2
        ref = (base["dynamic_mape"] + base["static_mape"]) / 2
        beats = int((both < ref.reindex(both.index)).sum())
        cov_s = " / ".join(f"{c.min():.2f}–{c.max():.2f}" if len(c) else "–"
                           for c in (g["coverage"].dropna(), g["coverage_spread"].dropna(),
                                     g["coverage_served"].dropna()))
        served = g["coverage_served"].dropna()
        band = f"{int(((served >= 0.85) & (served <= 0.95)).sum())} of {len(served)}" if len(served) else "–"
        lines.append(f"| {model} | {g['dynamic_mape'].median():.1f} / {g['dynamic_mape'].max():.1f} | "
                     f"{g['static_mape'].median():.1f} / {g['static_mape'].max():.1f} | "
                     f"{g['peak_error'].median():.1f} | "
                     f"{cov_s} | {band} | {beats} of {len(g)} |")
    ex = meta["extrapolation"]
    warned = ", ".join(m for m, w in ex["warned"].items() if w) or "none"
    lines += ["", "## Which predictions to distrust", "",
              "Error score (`scaling.evaluation.conformal.ErrorScore`): the probability that a row is more than "
              "10 % off, by a logistic regression on what is known before the truth (the ensemble's σ of ln δ1, "
              "the row's input novelty, the size of the correction |ln δ1|, the machine's design distance, whether "
              "the bucket is at rest), fitted on the calibration machines; it warns above a threshold that keeps the "
              "warnings to at most 5 % of the rows of 90 % of the calibration machines "
              "(`scaling.evaluation.conformal.machine_level_quantile`). AUROC: how well a score "
              "separates the rows of the test machines more than 10 % off from the rest (0.5 = chance). "
              f"Design distance alone: threshold {ex['threshold']:.2f} (95th percentile of the calibration "
              f"machines); machines it warns on: {warned}.", "",
              "| model | AUROC: error score | rows warned on, median / max over the drawn test machines | "
              "AUROC: served risk (rows > 10 % off) | served risk, rows > 3 % / > 5 % off | "
              "rows warned on by it | rows ≤ 10 % off warned on by it (false alarms) | "
              "AUROC: design distance | AUROC: ensemble spread |",
              "|---|---|---|---|---|---|---|---|---|"]

    def fmt(x: float | None) -> str:
        return "–" if x is None or not np.isfinite(x) else f"{x:.2f}"

    def shares(table: dict[str, float]) -> str:
        share = pd.Series({m: v for m, v in table.items() if m not in ("mini", "wa475")}, dtype=float)
        return f"{100 * share.median():.1f} % / {100 * share.max():.1f} %" if len(share) else "–"

    for name, a in ex["auroc_design_distance"].items():
        at = ex.get("auroc_row_risk_at", {}).get(name, {})
        lines.append(f"| {name} | {fmt(ex['auroc_error_score'].get(name))} | "
                     f"{shares(ex['warn_share'].get(name, {}))} | {fmt(ex['auroc_row_risk'].get(name))} | "
                     f"{' / '.join(fmt(at.get(k)) for k in ('0.03', '0.05'))} | "
                     f"{shares(ex['row_risk_warn_share'].get(name, {}))} | "
                     f"{shares(ex.get('row_risk_false_alarms', {}).get(name, {}))} | {fmt(a)} | "
                     f"{fmt(ex['auroc_ensemble_spread'].get(name))} |")
    lines += ["", "Served risk (`scaling.evaluation.conformal.RowRisk`, what a checkpoint such as `statics-pl` "
              "computes per row): P(F21 more than 10 % off) read off the served interval "
              "(`scaling.evaluation.conformal.IntervalRisk`): the share of the median calibration machine's rows "
              "whose residual over its width exceeds the miss line over this row's width (the width learnt from "
              "the novelty of the row's features, |ln δ1| and whether the bucket is at rest); it warns where that "
              "is at least 0.5. Its AUROC is also given for rows more than 3 % and 5 % off: few rows are more than "
              "10 % off, so that figure rests on a handful of rows of a few machines."]
    if ex.get("row_risk_misses"):
        lines += ["", "Where the rows more than 10 % off lie: with the tilt cylinder at an end of its stroke "
                  "(`scaling.evaluation.metrics.at_stroke_end`), its end stop carries load no pressure shows and F21 "
                  "is not the linkage statics the models scale; a served model flags such rows "
                  "(`ScaledForce.stroke_end`, `zoo.EndStopWarning`) beside its risk. Over the drawn test machines:", "",
                  "| model | rows at a stroke end, median / max | rows > 10 % off | of them at a stroke end | "
                  "warned by the risk | flagged by the risk or the stroke end |", "|---|---|---|---|---|---|"]
        for name, per in ex["row_risk_misses"].items():
            drawn = {m: v for m, v in per.items() if m not in ("mini", "wa475")}
            total = {k: sum(v[k] for v in drawn.values()) for k in ("rows", "at_stroke_end", "warned", "flagged")}
            lines.append(f"| {name} | {shares(ex['stroke_end_share'].get(name, {}))} | {total['rows']} | "
                         f"{total['at_stroke_end']} | {total['warned']} | {total['flagged']} |")
    lines += ["", "## Every test machine", "",
              "| machine | model | source | dynamic MAPE / median [%] | static MAPE / median [%] | peak [%] | "
              "coverage: learned / spread / served | rows > 10 % off |", "|---|---|---|---|---|---|---|---|"]
    for r in table.itertuples():
        lines.append(f"| {r.machine} | {r.model} | {r.source} | {r.dynamic_mape:.1f} / {r.dynamic_median:.1f} | "
                     f"{r.static_mape:.1f} / {r.static_median:.1f} | {r.peak_error:.1f} | "
                     f"{r.coverage:.2f} / {r.coverage_spread:.2f} / {r.coverage_served:.2f} | "
                     f"{100 * r.miss_share:.0f} % |")
    share = pd.Series(meta["relief_share"])
    lines += ["", f"Fit seconds: {', '.join(f'{k} {v:.0f}' for k, v in meta['fit_seconds'].items())}.", "",
              "## Cylinders at relief", "",
              "Share of dig-episode rows with the lift or tilt cylinder at ≥ 98 % of its relief pressure: "
              f"median {share.median():.2f}, range {share.min():.2f}–{share.max():.2f} over all "
              f"{len(share)} machines (ER12 {share.get('er12', float('nan')):.2f}). A real standard dig reaches "
              "relief in short peaks only; here the relief valve sets the pin forces on a large share of rows.", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
