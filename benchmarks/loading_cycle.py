"""KPIs of the scripted short loading cycle (WheelLoaderLoadTruck-v0) per scale and soil, against published figures.

One episode per (scale, soil, seed), seeds 0, 1, 2 by default, default truck (4 heaped buckets, done at 95 %):
truck payload rate (t/h of simulated time), specific energy (hydraulic + drive work per kg delivered, J/kg), cycle
time (time per pass, s and Froude times √(L/g)), passes, spill (kg and % of payload), payload error against the
target. The published figures in :data:`PUBLISHED` are compared in Froude times: a real machine's cycle of T s at
boom length L_r corresponds to T / √(L_r/g) Froude times.

Run: ``python benchmarks/loading_cycle.py [--scales mini,er12,wa475] [--soils gravel,clay_loam] [--seeds 0,1,2]``
(≈ 4 min on one core for the 18 default episodes); writes ``benchmarks/results/loading_cycle.{md,csv,png}``.
"""

from __future__ import annotations

import argparse
import csv
import datetime as dt
import math
import os
import platform
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

import scaletwin_envs
from scaletwin_envs.envs.load_truck import ENV_ID
from scaletwin_envs.host import git_revision, host_line
from scaletwin_envs.policies.loading_cycle import LoadingCyclePolicy
from scaletwin_envs.specs.loader import GRAVITY

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results"
#: Published figures (cycle time of a short loading cycle, passes per truck, bucket fill), with sources.
PUBLISHED: list[tuple[str, str, str]] = [
    (
        "≤ 30 s from bucket fill to bucket dump: 'optimum industry standard' cycle "
        "(Caterpillar application specialist)",
        "ForConstructionPros, 'Optimizing Wheel Loader Cycle Times: When Even Seconds Count'",
        "https://www.forconstructionpros.com/equipment/earthmoving/loaders/article/12129273/"
        "optimizing-wheel-loader-cycle-times-when-even-seconds-count",
    ),
    (
        "30 s fill-dump-return for a 3 yd³ (2.3 m³) loader into 9 yd³ trucks; 2-3 passes per truck optimal; 85 % fill "
        "needs 3.5 passes",
        "Construction Equipment, 'Take-Charge Wheel Loader Operators Fill Trucks Faster' (2010, Caterpillar trainer)",
        "https://constructionequipment.com/take-charge-wheel-loader-operators-fill-trucks-faster",
    ),
    (
        "Q = q·60·E/Cm; bucket fill factor 1.0-1.1 easy, 0.85-0.95 average (unscreened gravel, clay), 0.75-0.8 "
        "difficult loading",
        "Komatsu Specifications & Application Handbook, 'Dozer shovels and wheel loaders'",
        "https://ru.scribd.com/document/143810369/komat",
    ),
    (
        "basic cycle time plus material/pile/operation adjustments in minutes (e.g. +0.02 min truck-dumped pile)",
        "Caterpillar Performance Handbook, ed. 40, p. 12-106 'Wheel Loader - Cycle Time'",
        "https://www.scribd.com/doc/305991987/Wheel-Loader-Cycle-Time",
    ),
]
REAL_CYCLE_S = 30.0  # s: the published short cycle above
REAL_BOOM_M = 2.6  # m: boom length assumed for a 2.3 m³ (3 yd³) loader (er12's 2.29 m boom carries ~1.2 m³)


def run(scale: str, soil: str, seed: int = 0) -> dict[str, Any]:
    """One scripted episode reset with ``seed``; its KPIs (SI units; ``cycle_tf`` in Froude times)."""
    env = gym.make(ENV_ID, scale=scale, soil=soil)
    u = env.unwrapped
    obs, info = env.reset(seed=seed)
    policy = LoadingCyclePolicy()
    t0 = time.perf_counter()
    while True:
        obs, _, term, trunc, info = env.step(policy.act(obs))
        if term or trunc:
            break
    tf = u.loader.froude_time
    payload, passes, t = info["truck_payload"], info["passes"], info["time"]
    work = info["hydraulic_work"] + info["drive_work"]
    return {
        "scale": scale,
        "soil": soil,
        "seed": seed,
        "boom_m": round(u.length, 3),
        "froude_s": round(tf, 4),
        "success": bool(info["success"]),
        "sim_error": info["sim_error"] or "",
        "passes": passes,
        "time_s": round(t, 2),
        "payload_kg": round(payload, 2),
        "target_kg": round(info["target_payload"], 2),
        "t_per_h": round(payload / 1e3 / (t / 3600.0), 4),
        "J_per_kg": round(work / payload, 2) if payload > 0 else math.nan,
        "cycle_s": round(t / passes, 2) if passes else math.nan,
        "cycle_tf": round(t / passes / tf, 1) if passes else math.nan,
        "spill_kg": round(info["spilled_mass"], 3),
        "spill_pct": round(100.0 * info["spilled_mass"] / payload, 2) if payload > 0 else math.nan,
        "payload_error": round(info["payload_error"], 4),
        "wall_s": round(time.perf_counter() - t0, 1),
    }


def write(rows: list[dict[str, Any]]) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    with (OUT / "loading_cycle.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    real_tf = REAL_CYCLE_S / math.sqrt(REAL_BOOM_M / GRAVITY)
    now = dt.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z")
    lines = [
        f"# Loading cycle KPIs ({now})",
        "",
        f"Host: {host_line()}; {os.cpu_count()} cores; load {os.getloadavg()[0]:.1f}; python "
        f"{platform.python_version()}; scaletwin {scaletwin_envs.__version__}; git {git_revision()}.",
        "",
        "Scripted cycle (`LoadingCyclePolicy`: scripted TUNED dig with a lift-crowd cut on a dug face, boom "
        "raised out of the pile before reversing, proportional pitch hold and ramped lift while carrying, last "
        "pass shedding over the pile what the truck does not need), `WheelLoaderLoadTruck-v0` "
        "defaults (truck 4 heaped buckets, done at 95 %, 600 Froude times; faces steeper than repose slump in "
        "cohesionless soil), seeds "
        f"{', '.join(sorted({str(r['seed']) for r in rows}))}. "
        "Rates over simulated time, no operator or truck-exchange delays.",
        "",
        "| scale | soil | seed | L [m] | done | passes | time [s] | payload/target | t/h | J/kg | cycle [s] | "
        "cycle [√(L/g)] | spill [kg] (%) | payload error |",
        "|" + "---|" * 14,
    ]
    for r in rows:
        done = "yes" if r["success"] else f"no{' ' + r['sim_error'] if r['sim_error'] else ''}"
        lines.append(
            f"| {r['scale']} | {r['soil']} | {r['seed']} | {r['boom_m']} | {done} | {r['passes']} | {r['time_s']} | "
            f"{r['payload_kg']:.0f}/{r['target_kg']:.0f} | {r['t_per_h']} | {r['J_per_kg']} | "
            f"{r['cycle_s']} | {r['cycle_tf']} | {r['spill_kg']} ({r['spill_pct']}) | "
            f"{r['payload_error']:+.3f} |"
        )
    lines += ["", "## Published figures", "", "| figure | source |", "|---|---|"]
    lines += [f"| {fig} | [{src}]({url}) |" for fig, src, url in PUBLISHED]
    done = [r for r in rows if r["success"]]
    tfs = [r["cycle_tf"] for r in done] or [math.nan]
    errors = [abs(r["payload_error"]) for r in done] or [math.nan]
    passes = sorted({r["passes"] for r in done})
    lines += [
        "",
        f"Comparison: a {REAL_CYCLE_S:.0f} s cycle of a loader with a ~{REAL_BOOM_M} m boom (assumed for "
        f"the 2.3 m³ class) is {real_tf:.0f} Froude times. Simulated cycles: "
        f"{min(tfs):.0f}-{max(tfs):.0f} Froude times per pass in the episodes that filled their truck "
        "(the failed ones are in the table), "
        f"i.e. {min(tfs) / real_tf:.1f}-{max(tfs) / real_tf:.1f} × the published short cycle. Passes per "
        f"4-bucket truck: {', '.join(map(str, passes))} (the published 2-3 are for trucks matched to 2-3 buckets; "
        "a 4-bucket truck needs 4 at the 0.9-1.1 bucket fill of the scripted dig); payload within "
        f"{100 * max(errors):.1f} % of the target (the last pass takes a partial bucket).",
        "",
    ]
    if any(r["scale"] == "mini" and r["soil"] == "clay_loam" and not r["success"] for r in rows):
        lines += [
            "Not filled: the mini (L = 0.33 m, 11 kg) in clay loam. Cohesion does not scale with size: 30 kPa is "
            "c/(γL) = 6.5 at the mini against 0.9 at the er12, and at an edge depth of 0.02 L the cutting "
            "resistance is already 2.6 × the mini's weight against a rimpull of 0.6 × its weight, so it stalls at "
            "the toe and scrapes a few hundredths of a bucket per pass (the dig env's scripted and learned digs fill "
            "0.004-0.016 there too, benchmarks/results/policy_kpis.md): a physical limit of a scale model in "
            "unscaled soil, not of the cycle.",
            "",
        ]
    (OUT / "loading_cycle.md").write_text("\n".join(lines))
    fig, ax = plt.subplots(1, 2, figsize=(max(10, 0.9 * len(rows)), 4.5))
    labels = [f"{r['scale']}\n{r['soil']}\n{r['seed']}" for r in rows]
    ax[0].bar(labels, [r["cycle_tf"] for r in rows])
    ax[0].axhline(real_tf, color="k", ls="--", label=f"published {REAL_CYCLE_S:.0f} s at L={REAL_BOOM_M} m")
    ax[0].set_ylabel("cycle time per pass [√(L/g)]")
    ax[0].legend()
    ax[1].bar(labels, [r["J_per_kg"] for r in rows])
    ax[1].set_ylabel("hydraulic + drive work per kg delivered [J/kg]")
    fig.suptitle("Scripted loading cycle, WheelLoaderLoadTruck-v0")
    fig.tight_layout()
    fig.savefig(OUT / "loading_cycle.png", dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scales", default="mini,er12,wa475")
    parser.add_argument("--soils", default="gravel,clay_loam")
    parser.add_argument("--seeds", default="0,1,2", help="reset seeds, one episode each (default: 0,1,2)")
    args = parser.parse_args()
    rows = []
    for scale in args.scales.split(","):
        for soil in args.soils.split(","):
            for seed in args.seeds.split(","):
                rows.append(run(scale, soil, int(seed)))
                print(rows[-1], flush=True)
    write(rows)


if __name__ == "__main__":
    main()
