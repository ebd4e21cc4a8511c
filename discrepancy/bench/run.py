"""The proof: plant physics in the twin, hide it, run the diagnosis blind and score it.

Each case (:mod:`discrepancy.bench.cases`) records two closed-loop dig cycles of the planted twin (one analysed,
one held out), diagnoses them against the nominal twin, and is scored (:mod:`discrepancy.bench.scoring`) per planted
effect: identification, localisation, parameter error and interval coverage, residual reduction on the held-out
cycle; false discoveries on null cases; ``unexplained`` on out-of-catalogue cases. Cases run in parallel through
the executor seam (:func:`scaletwin_envs.parallel.make_executor`); every result is a JSON-able dict.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np

from discrepancy.bench.cases import Case, make_cases
from discrepancy.bench.scoring import truth_pairs
from discrepancy.bench.synth import Synthetic, record
from discrepancy.data.episode import signal_spread
from discrepancy.effects import UNEXPLAINED, Effect, Scales
from discrepancy.pipeline import DiagnoseOptions, Diagnosis, diagnose
from scaletwin_envs.parallel import make_executor


def _matches(planted: list[Effect], scales: Scales, d: Diagnosis) -> list[dict[str, Any]]:
    """Per planted effect: named (name + target), named by name only, parameter error and coverage."""
    out = []
    for truth in planted:
        hit = next((e for e in d.effects if e.effect == truth.name and _same_target(e.target, truth)), None)
        row: dict[str, Any] = {"effect": truth.name, "target": truth.target,
                               "pi": truth.to_pi(scales), "named": hit is not None,
                               "name_only": any(e.effect == truth.name for e in d.effects),
                               "in_confounded": any(truth.label() in e.confounded_with for e in d.effects)}
        if hit is not None:
            true, est = np.array(list(truth.params.values())), np.array([hit.parameters[k] for k in truth.params])
            row["param_error"] = float(np.linalg.norm(est - true) / max(np.linalg.norm(true), 1e-300))
            row["covered"] = all(hit.interval[k][0] <= v <= hit.interval[k][1] for k, v in truth.params.items())
        out.append(row)
    return out


def _same_target(reported: str | None, truth: Any) -> bool:
    return truth.spec.target_kind in ("payload", "soil") or reported == truth.target


def _reduction(syn: Synthetic, d: Diagnosis, names: set[str]) -> float | None:
    """1 − |corrected − clean| / |twin − clean| on the held-out cycle, over the effect's signals (noise-scaled)."""
    runs = d.traces.get(syn.clean.name)
    if not runs or not names:
        return None
    num = den = 0.0
    for s in names:
        sd = syn.noise_sd.get(s) or 1.0
        clean = syn.clean.signals[s]
        den += float(np.nansum(((runs["twin"].signals[s] - clean) / sd) ** 2))
        num += float(np.nansum(((runs["corrected"].signals[s] - clean) / sd) ** 2))
    return None if den <= 0 else float(1.0 - np.sqrt(num / den))


def run_case(case: Case, options: DiagnoseOptions | None = None) -> dict[str, Any]:
    """Generate, diagnose and score one case."""
    t0 = time.perf_counter()
    nominal = record(case.twin, [], 0.0, case.twin.seed)
    scales = Scales.of(case.twin.loader, case.twin.soil, signal_spread(nominal.clean.signals))
    planted = case.effects(scales)
    real = record(case.twin, planted, case.noise, case.twin.seed, case.extra(), name=f"case{case.index}")
    held = record(case.twin, planted, case.noise, case.held_out_seed, case.extra(), name=f"case{case.index}_held_out")
    t1 = time.perf_counter()
    d = diagnose(real.noisy, case.twin, held_out=[held.noisy], options=options)
    named = [(e.effect, e.target) for e in d.effects]
    truth, dont_care = truth_pairs(real, d)
    located = {(loc.signal, loc.phase) for loc in d.located}
    reduction = _reduction(held, d, {s for s, _ in truth}) if planted else None
    return {
        "index": case.index, "kind": case.kind, "scale": case.meta.get("scale"), "soil": case.meta.get("soil"),
        "noise": case.noise, "ooc": case.ooc, "planted": [e.label() for e in planted], "named": named,
        "unexplained": any(n == UNEXPLAINED for n, _ in named), "matches": _matches(planted, scales, d),
        "truth_pairs": sorted(map(list, truth)), "dont_care": sorted(map(list, dont_care)),
        "located_pairs": sorted(map(list, located)), "reduction": reduction, "diagnosis_s": d.timings["total"],
        "generate_s": t1 - t0, "timings": d.timings, "simulations": d.simulations,
        "budget": d.budget.to_dict() if d.budget else None, "workers": (options or DiagnoseOptions()).workers,
        "load": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
    }


def run_bench(cases: int, seed: int, workers: int = 1, on_result: Callable[[dict[str, Any]], None] | None = None,
              options: DiagnoseOptions | None = None) -> list[dict[str, Any]]:
    """Run ``cases`` cases (``workers`` processes, one diagnosis per process, each with ``options``, e.g. its own
    replay workers); results in case order."""
    todo = make_cases(cases, seed)
    results: dict[int, dict[str, Any]] = {}
    task = partial(run_case, options=options)
    for i, result in make_executor(workers if workers > 1 else "serial").map_unordered(task, todo):
        results[i] = result
        if on_result is not None:
            on_result(result)
    return [results[i] for i in sorted(results)]
