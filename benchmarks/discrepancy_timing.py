"""Time one diagnosis per pipeline step: replay, null, locate, redundancy, identify, fit, compare.

Diagnoses a few planted recordings (a null, one effect, two effects) at the three presets, plus benchmark cases
(``--bench-cases SEED:INDEX``, as ``scaletwin bench-discrepancy`` makes them, with their noise family and input
condition; by default the first three two-effect cases of seed 0), with 2 worker processes
(``--workers``), and writes a table of seconds per step, the replays, whether the search budget cut the search,
and the 1-min load average when each diagnosis ended.

Run: ``python benchmarks/discrepancy_timing.py [--workers 2] [--out benchmarks/results/discrepancy_timing.md]``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import tempfile
from pathlib import Path

import numpy as np

from discrepancy import DiagnoseOptions, Effect, Scales, TwinSpec, diagnose
from discrepancy.bench.synth import record
from discrepancy.data.episode import signal_spread
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


#: Two-effect benchmark cases (seed:index; indices 2, 9 and 14 are the first "double" slots of the kind pattern).
#: The costliest cases of the old draw (before issue 14 widened it) no longer exist under the same keys.
WORST = ("0:2", "0:9", "0:14")


def bench_case(key: str, folder: Path) -> tuple[str, str, object, object]:
    """A benchmark case (``SEED:INDEX``; an old ``CASES:SEED:INDEX`` key is read as its last two fields) as (scale,
    label, twin, (real, held out)), its recordings delivered under the case's input condition (field logs written
    under ``folder``)."""
    from discrepancy.bench.cases import make_case
    from discrepancy.bench.sensor_noise import channel_range
    from discrepancy.bench.synth import field_recording, simulate, simulate_between, twin_file

    seed, index = (int(x) for x in key.split(":")[-2:])
    case = make_case(index, seed)
    nominal, control_dt = simulate(case.twin, [], case.twin.seed)
    scales = Scales.of(case.twin.loader, case.twin.soil, signal_spread(nominal.signals))
    ranges = {k: channel_range(v) for k, v in nominal.signals.items()}
    planted = case.effects(scales)
    recs = []
    for sub, (s, name) in enumerate(((case.twin.seed, f"case{index}"), (case.held_out_seed, f"case{index}_held_out"))):
        clean, _, between = simulate_between(case.twin, planted, s, case.extra(), name=name)
        recs.append(field_recording(clean, control_dt, case.noise, case.condition, ranges, sub, folder / key,
                                    between))
    twin = twin_file(case.twin, folder / key).as_posix() if case.condition.field_log else case.twin
    label = (f"bench seed {seed} #{index} ({case.noise.describe()}, {case.condition.describe()}): "
             + " + ".join(e.label() for e in planted))
    return str(case.meta.get("scale")), label, twin, (recs[0].noisy, recs[1].noisy)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, nargs="+", default=[2])
    ap.add_argument("--scales", nargs="+", default=["mini", "er12", "wa475"])
    ap.add_argument("--bench-cases", nargs="*", default=list(WORST), metavar="SEED:INDEX")
    ap.add_argument("--out", default="benchmarks/results/discrepancy_timing.md")
    args = ap.parse_args()
    todo = [(scale, label, twin, eps) for scale in args.scales for label, twin, eps in cases(scale)]
    logs = Path(tempfile.mkdtemp(prefix="discrepancy_timing_"))
    todo += [bench_case(key, logs) for key in args.bench_cases]
    rows = []
    started = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    for scale, label, twin, (real, held) in todo:
        for workers in args.workers:
            d = diagnose(real, twin, held_out=[held], options=DiagnoseOptions(workers=workers))
            named = ", ".join(e.effect for e in d.effects) or "-"
            cut = (d.budget.cut if d.budget else None) or "-"
            load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
            rows.append((scale, label, workers, named, d.simulations, cut, load,
                         [d.timings.get(s, 0.0) for s in STEPS]))
            print(rows[-1][:7], f"{d.timings['total']:.1f} s", flush=True)
    budget = DiagnoseOptions()
    lines = [f"# discrepancy timing ({started}, {platform.machine()}, {os.cpu_count()} cores, "
             f"python {platform.python_version()})", "",
             "Seconds per pipeline step of one diagnosis (one analysed cycle + one held-out cycle); search budget "
             f"{budget.budget} replays / {budget.time_budget:g} s (cut: what stopped the search short, if anything); "
             "load: 1-min load average when the diagnosis ended (other users' jobs included).", "",
             "| scale | case | workers | named | replays | cut | load avg | " + " | ".join(STEPS) + " |",
             "|---|---|---|---|---|---|---|" + "---|" * len(STEPS)]
    for scale, label, workers, named, sims, cut, load, t in rows:
        lines.append(f"| {scale} | {label} | {workers} | {named} | {sims} | {cut} | {load:.1f} | "
                     + " | ".join(f"{x:.1f}" for x in t) + " |")
    totals = np.array([r[-1][-1] for r in rows])
    lines += ["", f"Total per diagnosis: median {np.median(totals):.1f} s, max {totals.max():.1f} s."]
    text = "\n".join(lines) + "\n"
    print(text)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
