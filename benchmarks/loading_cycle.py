"""KPIs of the short loading cycle (WheelLoaderLoadTruck-v1) per dig policy, scale and soil, against published figures.

One episode per (dig, scale, soil, seed): the scripted cycle digging with the scripted dig and with the zoo's learned
bucket-fill policy, seeds 0, 1, 2 by default, default truck (4 heaped buckets, done at 95 %):
truck payload rate (t/h of simulated time), specific energy (hydraulic + drive work per kg delivered, J/kg), cycle
time (time per pass, s and Froude times √(L/g)), passes, spill (kg and % of payload), payload error against the
target, and the published productivity band of the machine
(:func:`scaletwin_envs.productivity.productivity_band`). The published figures
(:data:`scaletwin_envs.productivity.PUBLISHED`) are compared in Froude times: a real machine's cycle of T s at boom
length L_r corresponds to T / √(L_r/g) Froude times.

Run: ``python benchmarks/loading_cycle.py [--digs scripted,learned] [--scales mini,er12,wa475]
[--soils gravel,clay_loam] [--seeds 0,1,2]`` (≈ 8 min on one core for the 36 default episodes);
writes ``benchmarks/results/loading_cycle.{md,csv,png}``.
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
from scaletwin_envs.physics.bucket import heaped_capacity
from scaletwin_envs.policies.loading_cycle import LoadingCyclePolicy
from scaletwin_envs.productivity import CYCLE_S, FILL_FACTOR, PUBLISHED, REFERENCE_BOOM_M, productivity_band

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results"


def cycle_policy(dig: str) -> LoadingCyclePolicy:
    """The loading cycle with the scripted dig (``"scripted"``: :class:`FaceDigPolicy`, TUNED) or the zoo's learned
    bucket-fill policy (``"learned"``: ``bucketfill-ppo``, trained on the dig env only)."""
    if dig == "scripted":
        return LoadingCyclePolicy()
    if dig == "learned":
        import zoo

        return LoadingCyclePolicy(dig=zoo.load("bucketfill-ppo"))
    raise ValueError(f"dig must be 'scripted' or 'learned', got {dig!r}")


def run(scale: str, soil: str, seed: int = 0, dig: str = "scripted") -> dict[str, Any]:
    """One episode reset with ``seed``, the cycle digging with ``dig`` (see :func:`cycle_policy`); its KPIs (SI
    units; ``cycle_tf`` in Froude times)."""
    env = gym.make(ENV_ID, scale=scale, soil=soil)
    u = env.unwrapped
    obs, info = env.reset(seed=seed)
    policy = cycle_policy(dig)
    t0 = time.perf_counter()
    while True:
        obs, _, term, trunc, info = env.step(policy.act(obs))
        if term or trunc:
            break
    tf = u.loader.froude_time
    payload, passes, t = info["truck_payload"], info["passes"], info["time"]
    work = info["hydraulic_work"] + info["drive_work"]
    band = productivity_band(heaped_capacity(u.loader.geometry), u.soil.density, u.length)
    rate = payload / 1e3 / (t / 3600.0)
    return {
        "dig": dig,
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
        "t_per_h": round(rate, 4),
        "band_low": round(band.low, 4),
        "band_high": round(band.high, 4),
        "band": band.position(rate),
        "J_per_kg": round(work / payload, 2) if payload > 0 else math.nan,
        "cycle_s": round(t / passes, 2) if passes else math.nan,
        "cycle_tf": round(t / passes / tf, 1) if passes else math.nan,
        "spill_kg": round(info["spilled_mass"], 3),
        "spill_pct": round(100.0 * info["spilled_mass"] / payload, 2) if payload > 0 else math.nan,
        "payload_error": round(info["payload_error"], 4),
        "wall_s": round(time.perf_counter() - t0, 1),
    }


def band_summary(rows: list[dict[str, Any]]) -> str:
    """Where the filled episodes' t/h lie against the published band, per dig policy and soil."""
    parts = []
    for dig in dict.fromkeys(r["dig"] for r in rows):
        for soil in dict.fromkeys(r["soil"] for r in rows):
            done = [r for r in rows if r["dig"] == dig and r["soil"] == soil and r["success"]]
            if not done:
                continue
            counts = {p: sum(r["band"] == p for r in done) for p in ("below", "inside", "above")}
            ratio = [r["t_per_h"] / r["band_high"] for r in done]
            parts.append(f"{dig} dig in {soil}: {counts['inside']} of {len(done)} filled episodes inside, "
                         f"{counts['above']} above, {counts['below']} below (t/h / band top "
                         f"{min(ratio):.2f}-{max(ratio):.2f})")
    return "; ".join(parts) or "no episode filled its truck"


def write(rows: list[dict[str, Any]]) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    with (OUT / "loading_cycle.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    real_tf = min(productivity_band(1.0, 1.0, REFERENCE_BOOM_M).cycle_froude)
    now = dt.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z")
    lines = [
        f"# Loading cycle KPIs ({now})",
        "",
        f"Host: {host_line()}; {os.cpu_count()} cores; load {os.getloadavg()[0]:.1f}; python "
        f"{platform.python_version()}; scaletwin {scaletwin_envs.__version__}; git {git_revision()}.",
        "",
        "Scripted cycle (`LoadingCyclePolicy`: scripted TUNED dig with a lift-crowd cut on a dug face, boom "
        "raised out of the pile before reversing, proportional pitch hold and ramped lift while carrying, last "
        "pass shedding over the pile what the truck does not need), `WheelLoaderLoadTruck-v1` "
        "defaults (truck 4 heaped buckets, done at 95 %, 600 Froude times; faces steeper than repose slump in "
        "cohesionless soil), seeds "
        f"{', '.join(sorted({str(r['seed']) for r in rows}))}. "
        "Rates over simulated time, no operator or truck-exchange delays.",
        "",
        "The learned rows dig with the zoo's `bucketfill-ppo` (trained on the dig env alone, never on a dug face): "
        "after each dump the cycle brings the bucket back level on the ground to the dig env's start distance from "
        "the pile face (`CycleStage.RETURN`) and hands over to it.",
        "",
        "| dig | scale | soil | seed | L [m] | done | passes | time [s] | payload/target | t/h | published band "
        "[t/h] | J/kg | cycle [s] | cycle [√(L/g)] | spill [kg] (%) | payload error |",
        "|" + "---|" * 16,
    ]
    for r in rows:
        done = "yes" if r["success"] else f"no{' ' + r['sim_error'] if r['sim_error'] else ''}"
        lines.append(
            f"| {r['dig']} | {r['scale']} | {r['soil']} | {r['seed']} | {r['boom_m']} | {done} | {r['passes']} | "
            f"{r['time_s']} | "
            f"{r['payload_kg']:.0f}/{r['target_kg']:.0f} | {r['t_per_h']} | {r['band_low']:.4g}-{r['band_high']:.4g} "
            f"({r['band']}) | {r['J_per_kg']} | "
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
        f"Comparison: a {CYCLE_S[0]:.0f} s cycle of a loader with a ~{REFERENCE_BOOM_M} m boom (assumed for "
        f"the 2.3 m³ class) is {real_tf:.0f} Froude times. Simulated cycles: "
        f"{min(tfs):.0f}-{max(tfs):.0f} Froude times per pass in the episodes that filled their truck "
        "(the failed ones are in the table), "
        f"i.e. {min(tfs) / real_tf:.1f}-{max(tfs) / real_tf:.1f} × the published short cycle. Passes per "
        f"4-bucket truck: {', '.join(map(str, passes))} (the published 2-3 are for trucks matched to 2-3 buckets; "
        "a 4-bucket truck needs 4 at the 0.9-1.1 bucket fill of the scripted dig); payload within "
        f"{100 * max(errors):.1f} % of the target (the last pass takes a partial bucket).",
        "",
        "Productivity against the published band (`scaletwin_envs.productivity.productivity_band`: the handbook's "
        f"Q = ρ·V·K·3600/T with fill factor K {FILL_FACTOR[0]}-{FILL_FACTOR[1]} and cycles of {CYCLE_S[0]:.0f}-"
        f"{CYCLE_S[1]:.0f} s quoted for the 2.3 m³ class, Froude-scaled to each machine's boom; working time, no "
        "breaks): " + band_summary(rows) + ".",
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
    other = [r for r in rows if not r["success"] and not (r["scale"] == "mini" and r["soil"] == "clay_loam")]
    if other:
        lines += [
            "Not filled otherwise: " + "; ".join(
                f"{r['dig']} dig, {r['scale']} in {r['soil']}, seed {r['seed']}: truck at "
                f"{100 * (1 + r['payload_error']):.1f} % of its target after {r['passes']} passes when the episode "
                f"ended ({r['sim_error'] or 'horizon'})" for r in other) + ".",
            "",
        ]
    (OUT / "loading_cycle.md").write_text("\n".join(lines))
    fig, ax = plt.subplots(1, 2, figsize=(max(10, 0.9 * len(rows)), 4.5))
    labels = [f"{r['dig'][0]} {r['scale']}\n{r['soil']}\n{r['seed']}" for r in rows]
    ax[0].bar(labels, [r["cycle_tf"] for r in rows])
    ax[0].axhline(real_tf, color="k", ls="--", label=f"published {CYCLE_S[0]:.0f} s at L={REFERENCE_BOOM_M} m")
    ax[0].set_ylabel("cycle time per pass [√(L/g)]")
    ax[0].legend()
    ax[1].bar(labels, [r["J_per_kg"] for r in rows])
    ax[1].set_ylabel("hydraulic + drive work per kg delivered [J/kg]")
    fig.suptitle("Loading cycle (s: scripted dig, l: learned dig), WheelLoaderLoadTruck-v1")
    fig.tight_layout()
    fig.savefig(OUT / "loading_cycle.png", dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scales", default="mini,er12,wa475")
    parser.add_argument("--soils", default="gravel,clay_loam")
    parser.add_argument("--seeds", default="0,1,2", help="reset seeds, one episode each (default: 0,1,2)")
    parser.add_argument("--digs", default="scripted,learned", help="dig policies in the cycle (default: both)")
    args = parser.parse_args()
    rows = []
    for dig in args.digs.split(","):
        for scale in args.scales.split(","):
            for soil in args.soils.split(","):
                for seed in args.seeds.split(","):
                    rows.append(run(scale, soil, int(seed), dig))
                    print(rows[-1], flush=True)
    write(rows)


if __name__ == "__main__":
    main()
