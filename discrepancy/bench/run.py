"""The proof: plant physics in the twin, hide it, run the diagnosis blind and score it.

Each case (:mod:`discrepancy.bench.cases`) records two closed-loop dig cycles of the planted twin (one analysed,
one held out), reads them through the case's sensors (:mod:`discrepancy.bench.sensor_noise`), delivers them under
its input condition (:mod:`discrepancy.bench.logs`: in memory, or a CSV field log without seed read by the tool's
own loader), diagnoses them against the nominal twin, and is scored (:mod:`discrepancy.bench.scoring`) per planted
effect: identification (strict and as a set of indistinguishable explanations), localisation, parameter error and
interval coverage, residual after/before on the held-out cycle; false discoveries on null cases; ``unexplained``
on out-of-catalogue cases. A case that raises is recorded as an error (type and message) and the benchmark goes
on. Cases run in parallel through the executor seam (:func:`scaletwin_envs.parallel.make_executor`); every result
is a JSON-able dict.
"""

from __future__ import annotations

import os
import re
import tempfile
import time
import traceback
from collections.abc import Callable, Collection, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from discrepancy.bench.cases import Case, make_cases
from discrepancy.bench.logs import Condition
from discrepancy.bench.scoring import truth_pairs
from discrepancy.bench.sensor_noise import channel_range
from discrepancy.bench.synth import (
    Synthetic,
    aligned,
    field_recording,
    nominal_replay,
    simulate,
    simulate_between,
    twin_file,
)
from discrepancy.data.episode import signal_spread
from discrepancy.effects import UNEXPLAINED, Effect, Scales
from discrepancy.pipeline import DiagnoseOptions, Diagnosis, diagnose
from discrepancy.twin.spec import TwinSpec
from scaletwin_envs.parallel import make_executor

#: A named effect counts "as a set" when the truth is it or one of its alternatives and the set has at most this
#: many members (issue 14: report the indistinguishable explanations rather than pick one; a set larger than three
#: says little).
MAX_SET = 3
_LABEL = re.compile(r"^\s*(?P<effect>[^:\[\]]+?)\s*(?:[:\[]\s*(?P<target>[^\]]*?)\s*\]?)?\s*$")


def parse_label(label: str) -> tuple[str, str | None]:
    """``"effect:target"`` or ``"effect[target]"`` → (effect, target or None)."""
    m = _LABEL.match(str(label))
    if not m:
        return str(label), None
    return m["effect"], (m["target"] or None)


def _same_target(reported: str | None, truth: Effect) -> bool:
    return truth.spec.target_kind in ("payload", "soil") or reported == truth.target


def _matches(planted: list[Effect], scales: Scales, d: Diagnosis) -> list[dict[str, Any]]:
    """Per planted effect: named (name + target), named as a set (the truth among the named effect's
    ``alternatives``, or among what a cleared start check found indistinguishable from the pile, the pile counted;
    set ≤ :data:`MAX_SET`), by name only, parameter error and coverage."""
    sets = [[(e.effect, e.target), *map(parse_label, getattr(e, "alternatives", None) or [])] for e in d.effects]
    if d.start_check is not None and d.start_check.cleared:
        sets.append([("pile", None), *map(parse_label, d.start_check.indistinguishable)])
    out = []
    for truth in planted:
        hit = next((e for e in d.effects if e.effect == truth.name and _same_target(e.target, truth)), None)
        in_set = any(len(set(members)) <= MAX_SET and any(n == truth.name and _same_target(t, truth)
                                                          for n, t in members) for members in sets)
        row: dict[str, Any] = {"effect": truth.name, "target": truth.target,
                               "pi": truth.to_pi(scales), "named": hit is not None, "named_as_set": in_set,
                               "name_only": any(e.effect == truth.name for e in d.effects),
                               "in_confounded": any(truth.label() in e.confounded_with for e in d.effects)}
        if hit is not None:
            true, est = np.array(list(truth.params.values())), np.array([hit.parameters[k] for k in truth.params])
            row["param_error"] = float(np.linalg.norm(est - true) / max(np.linalg.norm(true), 1e-300))
            row["covered"] = all(hit.interval[k][0] <= v <= hit.interval[k][1] for k, v in truth.params.items())
            row["estimate"] = {k: float(hit.parameters[k]) for k in truth.params}
            row["truth"] = {k: float(v) for k, v in truth.params.items()}
            row["interval"] = {k: [float(hit.interval[k][0]), float(hit.interval[k][1])] for k in truth.params}
        out.append(row)
    return out


def _after_before(syn: Synthetic, d: Diagnosis, names: set[str]) -> float | None:
    """|corrected − reading| / |twin − reading| on the held-out cycle over the effect's signals (noise-scaled; the
    reading: what noise-free sensors of the case deliver, ``Synthetic.reading``): the residual after the correction
    relative to before (0 perfect, 1 no change)."""
    runs = d.traces.get(syn.noisy.name)
    ep = next((h for h in d.held_out if h.name == syn.noisy.name), None)
    if not runs or not names or ep is None:
        return None
    clean = aligned(syn.reading if syn.reading is not None else syn.clean, ep.time)
    num = den = 0.0
    for s in names:
        if s not in runs["twin"].signals or s not in runs["corrected"].signals:
            continue
        sd = syn.noise_sd.get(s) or 1.0
        den += float(np.nansum(((runs["twin"].signals[s] - clean.signals[s]) / sd) ** 2))
        num += float(np.nansum(((runs["corrected"].signals[s] - clean.signals[s]) / sd) ** 2))
    return None if den <= 0 else float(np.sqrt(num / den))


def _input_report(d: Diagnosis) -> dict[str, Any] | None:
    """What the tool's loader did to the analysed log (resampling, offset, missing channels), when it says."""
    report = getattr(d.train, "input_report", None)
    return report.to_dict() if hasattr(report, "to_dict") else None


def _base(case: Case) -> dict[str, Any]:
    """What identifies a case in its result row (also when it failed)."""
    return {"index": case.index, "key": case.key(), "seed": case.seed, "kind": case.kind,
            "family": case.noise.family, "condition": case.condition.name, "noise": case.noise.describe(),
            "noise_level": case.noise.level, "input": case.condition.describe(), "scale": case.meta.get("scale"),
            "soil": case.meta.get("soil"), "ooc": case.ooc, "case": case.describe()}


def run_case(case: Case, options: DiagnoseOptions | None = None, folder: str | None = None) -> dict[str, Any]:
    """Generate, diagnose and score one case; an exception becomes ``{"error": ...}`` in the result."""
    base = _base(case)
    base["load"] = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    try:
        if folder is None:
            with tempfile.TemporaryDirectory(prefix=f"bench{case.index}_") as tmp:
                return {**base, **_run(case, options, Path(tmp))}
        return {**base, **_run(case, options, Path(folder) / f"case{case.index:04d}")}
    except Exception as exc:  # one case must never stop the benchmark: record what went wrong
        return {**base, "error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc(limit=6)}


def _run(case: Case, options: DiagnoseOptions | None, folder: Path) -> dict[str, Any]:
    t0 = time.perf_counter()
    nominal, control_dt = simulate(case.twin, [], case.twin.seed)
    scales = Scales.of(case.twin.loader, case.twin.soil, signal_spread(nominal.signals))
    ranges = {k: channel_range(v) for k, v in nominal.signals.items()}
    planted = case.effects(scales)
    cond: Condition = case.condition
    recs = []
    for sub, (seed, name) in enumerate(((case.twin.seed, f"case{case.index}"),
                                        (case.held_out_seed, f"case{case.index}_held_out"))):
        clean, _, between = simulate_between(case.twin, planted, seed, case.extra(), name=name)
        recs.append(field_recording(clean, control_dt, case.noise, cond, ranges, sub, folder, between))
    real, held = recs
    # the scoring's reference: the nominal twin on the analysed cycle's commands, read by the same sensors and log
    ref_clean, ref_between = nominal_replay(case.twin, real.clean)
    reference = field_recording(ref_clean, control_dt, case.noise, cond, ranges, 0, folder / "nominal", ref_between)
    if cond.field_log:
        for r in recs:
            if r.noisy.seed is not None:
                raise AssertionError(f"{r.path}: a field log must not carry a reset seed")
    twin: TwinSpec | str = twin_file(case.twin, folder).as_posix() if cond.field_log else case.twin
    t1 = time.perf_counter()
    d = diagnose(real.noisy, twin, held_out=[held.noisy], options=options)
    named = [(e.effect, e.target) for e in d.effects]
    truth, dont_care = truth_pairs(real, reference, d.train.time, d.names, None if d.noise is None else d.noise.twin,
                                   case.noise, ranges)
    located = {(loc.signal, loc.phase) for loc in d.located}
    after_before = _after_before(held, d, {s for s, _ in truth}) if planted else None
    return {
        "planted": [e.label() for e in planted], "named": named,
        "alternatives": [list(getattr(e, "alternatives", None) or []) for e in d.effects],
        "unexplained": any(n == UNEXPLAINED for n, _ in named), "matches": _matches(planted, scales, d),
        "truth_pairs": sorted(map(list, truth)), "dont_care": sorted(map(list, dont_care)),
        "located_pairs": sorted(map(list, located)), "after_before": after_before,
        "reduction": None if after_before is None else 1.0 - after_before, "diagnosis_s": d.timings["total"],
        "generate_s": t1 - t0, "timings": d.timings, "simulations": d.simulations,
        "budget": d.budget.to_dict() if d.budget else None, "workers": (options or DiagnoseOptions()).workers,
        "log_rows": real.meta.get("rows"), "tool_rows": len(d.train), "twin_seed_used": d.twin.seed,
        "input_report": _input_report(d), "true_offset_s": cond.offset_s,
        "start_check": d.start_check.to_dict() if d.start_check else None,
        "load": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
    }


def run_bench(cases: int, seed: int | Sequence[int], workers: int = 1,
              on_result: Callable[[dict[str, Any]], None] | None = None, options: DiagnoseOptions | None = None,
              families: tuple[str, ...] | None = None, conditions: tuple[str, ...] | None = None,
              skip: Collection[str] = (), folder: str | None = None) -> list[dict[str, Any]]:
    """Run the first ``cases`` cases of each master seed (``workers`` processes through the executor seam, one
    diagnosis per process, each with ``options``), leaving out those whose :meth:`Case.key` is in ``skip``
    (finished in an earlier run); ``on_result`` is called in this process as each case finishes. Results of this
    run in (seed, case) order; an interrupt (Ctrl-C) lets the finished cases through ``on_result`` first, then
    propagates.

    Args:
        families, conditions: restrict the noise families / input conditions dealt (default: all).
        folder: keep each case's field logs under ``folder/caseNNNN`` (default: a temporary folder per case).
    """
    todo = [c for c in planned_cases(cases, seed, families, conditions) if c.key() not in set(skip)]
    results: dict[int, dict[str, Any]] = {}
    task = partial(run_case, options=options, folder=folder)
    executor = make_executor(workers if workers > 1 else "serial")
    for i, result in executor.map_unordered(task, todo):
        results[i] = result
        if on_result is not None:
            on_result(result)
    return [results[i] for i in sorted(results)]


def planned_cases(cases: int, seed: int | Sequence[int], families: tuple[str, ...] | None = None,
                  conditions: tuple[str, ...] | None = None) -> list[Case]:
    """The first ``cases`` cases of each seed in ``seed``, families and conditions restricted where given."""
    kw = {k: tuple(v) for k, v in (("families", families), ("conditions", conditions)) if v}
    seeds = [seed] if isinstance(seed, int) else list(seed)
    return [c for s in seeds for c in make_cases(cases, s, **kw)]
