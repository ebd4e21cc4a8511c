"""The served ``statics-pl`` checkpoint on four machines that no choice of this project looked at (issue 13's table).

A new user's check: the machines of the issue that first showed the paper's models failing off their design (a
heavier λ 2.2 machine; λ 1.8 with a larger bucket and lower relief; λ 0.7 with 1.3× bores and 0.7× traction in clay
loam; the ``mini`` preset in sand), each simulated with the ER12 (5 digs and 2 hold episodes of 3 poses each,
seed 321 unless given), then F21 scaled from matched ER12 rows exactly as ``scaletwin predict`` serves it. Printed
per machine: rows judged (after start-up settling, F21 > 5 % of the peak), F21 error (mean, median, max), the
share of rows inside the served 90 % interval, the rows warned on (and the mean error of warned and other rows),
the rows more than 10 % off and the served risk's AUROC for them.

A second line per machine scales with ``statics-pl-ens`` from three calibrated machines at once
(``ScalingModel.scale_force_sources``, the interval and error score calibrated for three sources): the ER12, the
WA475 and a 0.4-scale machine of the product-line law (:data:`SOURCES`; none of them a target), each simulated
digging the target's soil, listed nearest the target in design first.

    python benchmarks/scaling_new_machines.py [SEED]
"""

from __future__ import annotations

import sys
import warnings

import numpy as np
import pandas as pd

import zoo
from scaletwin_envs.specs import LoaderSpec, make_loader
from scaling.data.product_line import add_design_signals, match_rows, nearest_machines
from scaling.data.recordings import DatasetSpec, generate_frame
from scaling.evaluation.conformal import auroc
from scaling.evaluation.generalisation import judged_rows

#: name → (machine, soil): the issue's four targets.
CASES = {
    "l2.2_mass1.15": (make_loader(2.2, distortion={"mass": 1.15}), "gravel"),
    "l1.8_bucket1.25_relief0.85": (make_loader(1.8, distortion={"bucket_size": 1.25, "pressure": 0.85}), "gravel"),
    "l0.7_bore1.3_traction0.7": (make_loader(0.7, distortion={"bore": 1.3, "traction": 0.7}), "clay_loam"),
    "mini_sand": (make_loader("mini"), "sand"),
}

#: The calibrated machines ``statics-pl-ens`` scales from (label → spec).
SOURCES = {"er12": make_loader("er12"), "wa475": make_loader("wa475"), "pl-0.4": make_loader(0.4)}


def check(name: str, spec: LoaderSpec, soil: str, seed: int, model: zoo.ScalingModel,
          ensemble: zoo.ScalingModel) -> str:
    """Two lines of results for machine ``spec`` digging ``soil`` (see the module docstring)."""
    # the ER12 and the target as one data set (as before the three-source line was added, so its recordings and
    # the first line stay the same), the other two sources as another with the same soil and seed
    specs = {**SOURCES, name: spec}
    parts = (("er12", "er12"), (name, spec.to_dict())), tuple((k, SOURCES[k].to_dict()) for k in SOURCES if k != "er12")
    frame = pd.concat([generate_frame(DatasetSpec(machines=m, soils=(soil,), pile_heights=(0.7,), dig_seeds=5,
                                                  hold_episodes=2, hold_poses=3, seed=seed), executor=1)
                       for m in parts], ignore_index=True)
    frame = add_design_signals(frame, specs)
    rows = {k: frame[frame["machine"] == k].reset_index(drop=True) for k in specs}
    tgt = rows[name][judged_rows(rows[name])].reset_index(drop=True)
    src = rows["er12"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the warning's content is what is printed below
        out = model.scale_force(src.iloc[match_rows(src, tgt)], tgt)
    order = nearest_machines(spec, SOURCES, len(SOURCES))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        multi = ensemble.scale_force_sources([rows[k].iloc[match_rows(rows[k], tgt)] for k in order], tgt)
    return (f"{name}: {len(tgt)} rows; statics-pl from the ER12: {summary(out, tgt)}\n"
            f"    statics-pl-ens from {'+'.join(order)}: {summary(multi, tgt)}")


def summary(out: zoo.ScaledForce, tgt: pd.DataFrame) -> str:
    """F21 error, interval coverage, warnings and the risk's AUROC of ``out`` against the target's F21."""
    truth = tgt["F21"].to_numpy(float)
    err = np.abs(out.force / truth - 1)
    lo, hi = out.interval
    covered = np.mean((truth >= lo) & (truth <= hi))
    assert out.risk is not None and out.warned is not None
    warned = out.warned
    bad = err > 0.1
    auc = auroc(out.risk, bad) if bad.any() and (~bad).any() else float("nan")
    warned_err = 100 * err[warned].mean() if warned.any() else float("nan")
    return (f"F21 error mean {100 * err.mean():.1f} %, median {100 * np.median(err):.1f} %, "
            f"max {100 * err.max():.1f} %; 90 % interval covers {covered:.2f}; warned {100 * warned.mean():.0f} % "
            f"(their error {warned_err:.1f} %, the rest {100 * err[~warned].mean():.1f} %); "
            f"> 10 % off {100 * bad.mean():.0f} %, risk AUROC {auc:.2f}")


if __name__ == "__main__":
    seed = int(sys.argv[1]) if len(sys.argv) > 1 else 321
    model, ensemble = zoo.load("statics-pl"), zoo.load("statics-pl-ens")
    for case, (machine, soil) in CASES.items():
        print(check(case, machine, soil, seed, model, ensemble), flush=True)
