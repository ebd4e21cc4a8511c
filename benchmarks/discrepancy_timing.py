"""Time one diagnosis per pipeline step: replay, null, locate, redundancy, identify, fit, compare.

Diagnoses a few planted recordings (a null, one effect, two effects) at the three presets with 1 and 2 worker
processes and writes a table of seconds per step (median over the runs of each setting).

Run: ``python benchmarks/discrepancy_timing.py [--workers 1 2] [--out benchmarks/results/discrepancy_timing.md]``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
from pathlib import Path

import numpy as np

from discrepancy import DiagnoseOptions, Effect, Scales, TwinSpec, diagnose
from discrepancy.episode import signal_spread
from discrepancy.synth import record
from scaletwin_envs.specs import make_loader, make_soil

STEPS = ("load", "replay", "null", "locate", "redundancy", "identify", "fit", "compare", "total")
PLANTS = {
    "null": [],
    "one effect": [("coulomb_friction", "bucket_hinge", {"friction": 0.006})],
    "two effects": [("payload_mass_error", "payload", {"mass_error": 0.2}),
                    ("sensor_bias", "F31", {"bias": 0.2})],
}


def cases(scale: str) -> list[tuple[str, object, object]]:
    twin = TwinSpec(make_loader(scale), make_soil("gravel"), {}, 21)
    scales = Scales.of(twin.loader, twin.soil, signal_spread(record(twin, [], 0.0, 21).clean.signals))
    out = []
    for label, plants in PLANTS.items():
        effects = [Effect.from_pi(n, t, p, scales) for n, t, p in plants]
        real = record(twin, effects, 0.01, 21, name=f"{scale}-{label}")
        held = record(twin, effects, 0.01, 22, name=f"{scale}-{label}-held")
        out.append((label, twin, (real.noisy, held.noisy)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--scales", nargs="+", default=["mini", "er12", "wa475"])
    ap.add_argument("--out", default="benchmarks/results/discrepancy_timing.md")
    args = ap.parse_args()
    rows = []
    for scale in args.scales:
        for label, twin, (real, held) in cases(scale):
            for workers in args.workers:
                d = diagnose(real, twin, held_out=[held], options=DiagnoseOptions(workers=workers))
                named = ", ".join(e.effect for e in d.effects) or "-"
                rows.append((scale, label, workers, named, d.simulations, [d.timings.get(s, 0.0) for s in STEPS]))
                print(rows[-1][:5], f"{d.timings['total']:.1f} s", flush=True)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [f"# discrepancy timing ({dt.date.today()}, {platform.machine()}, {os.cpu_count()} cores, load average "
             f"{load:.1f} at the end, python {platform.python_version()})", "",
             "Seconds per pipeline step of one diagnosis (one analysed cycle + one held-out cycle).", "",
             "| scale | case | workers | named | replays | " + " | ".join(STEPS) + " |",
             "|---|---|---|---|---|" + "---|" * len(STEPS)]
    for scale, label, workers, named, sims, t in rows:
        lines.append(f"| {scale} | {label} | {workers} | {named} | {sims} | " + " | ".join(f"{x:.1f}" for x in t)
                     + " |")
    totals = np.array([r[5][-1] for r in rows])
    lines += ["", f"Total per diagnosis: median {np.median(totals):.1f} s, max {totals.max():.1f} s."]
    text = "\n".join(lines) + "\n"
    print(text)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
