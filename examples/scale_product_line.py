"""Scale F21 from a calibrated machine to a machine of another design with the ``statics-pl`` checkpoint.

The source is the ER12 (its twin is calibrated: F21 known); the target is a machine of the product line that no
model was trained on (``--target-seed``/``--target-index`` draw it from the design space; linkage, hydraulics,
masses, bucket and traction all differ). Both dig gravel and hold their loaded bucket; the target's F21 is then
predicted from the ER12's matched rows and compared with the simulated truth.

With ``--sources 3`` the calibrated fleet is the ER12 and the 24 training machines of the product line (design
seed 0, as the leave-machine-out benchmark lays them out); the three nearest the target in design are simulated and
``statics-pl-ens`` scales from all three at once (``ScalingModel.scale_force_sources``: the geometric mean of their
F21, with the interval and error score calibrated for three sources).

Run: ``python examples/scale_product_line.py [--target-seed 7 --target-index 0] [--sources 3]`` (about a minute on
2 cores).
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np
import pandas as pd

import zoo
from scaletwin_envs.design_space import DesignSpace
from scaletwin_envs.specs import make_loader
from scaling.data.product_line import add_design_signals, match_rows, nearest_machines
from scaling.data.recordings import DatasetSpec, generate_frame
from scaling.evaluation.generalisation import LeaveMachineOut, judged_rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--target-seed", type=int, default=7, help="design-space seed of the target (default 7)")
    ap.add_argument("--target-index", type=int, default=0, help="index of the target in that draw (default 0)")
    ap.add_argument("--sources", type=int, choices=(1, 3), default=1,
                    help="calibrated machines to scale from: 1 (the ER12, statics-pl) or 3 (the nearest of the "
                         "line's training machines, statics-pl-ens)")
    args = ap.parse_args()
    target = DesignSpace().sample_one(args.target_seed, args.target_index)
    print(f"target {target.name}: λ {target.scale:.2f}, {target.validity.operating_mass_t:.1f} t, "
          f"tilt bore ×{target.distortion['tilt_bore']:.2f}, relief ×{target.distortion['pressure']:.2f}")
    if args.sources == 1:
        fleet = {"er12": make_loader("er12")}
    else:
        split = LeaveMachineOut().split()
        fleet = {m: split.specs[m] for m in split.train}
        fleet = {m: fleet[m] for m in nearest_machines(target.spec, fleet, args.sources)}
    specs = {"er12": make_loader("er12"), **fleet, target.name: target.spec}
    # the ER12 and the target as one data set (the same recordings whatever --sources), other sources apart
    parts = [(("er12", "er12"), (target.name, target.spec.to_dict())),
             tuple((k, v.to_dict()) for k, v in fleet.items() if k != "er12")]
    frame = pd.concat([generate_frame(DatasetSpec(machines=m, soils=("gravel",), pile_heights=(0.7,), dig_seeds=1,
                                                  hold_episodes=2, hold_poses=3, seed=123), executor=2)
                       for m in parts if m], ignore_index=True)
    frame = add_design_signals(frame, specs)
    tgt = frame[frame["machine"] == target.name].reset_index(drop=True)
    tgt = tgt[judged_rows(tgt)].reset_index(drop=True)
    # one matched row of each source per target row: same kind, nearest pose and fill
    sources = [src.iloc[match_rows(src, tgt)] for src in
               (frame[frame["machine"] == k].reset_index(drop=True) for k in fleet)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", zoo.ExtrapolationWarning)  # reported below, row by row
        if args.sources == 1:
            out = zoo.load("statics-pl").scale_force(sources[0], tgt)
        else:
            print(f"sources (nearest first): {', '.join(fleet)}")
            out = zoo.load("statics-pl-ens").scale_force_sources(sources, tgt)
    truth = tgt["F21"].to_numpy(float)
    err = np.abs(out.force / truth - 1)
    lo, hi = out.interval
    warned = out.warned
    print(f"{len(tgt)} rows: F21 error median {100 * np.median(err):.1f} %, mean {100 * np.mean(err):.1f} %, "
          f"max {100 * err.max():.1f} %; the 90 % interval covers {100 * np.mean((truth >= lo) & (truth <= hi)):.0f} %"
          f" of rows")
    if warned.any():
        print(f"risk: {int(warned.sum())} rows warned as likely more than 10 % off (their mean error "
              f"{100 * err[warned].mean():.1f} %, the other rows' {100 * err[~warned].mean():.1f} %)")
    else:
        print("risk: no row warned as likely more than 10 % off")

if __name__ == "__main__":
    main()
