"""Scores of the benchmark: where a planted effect truly shows, and the results table.

Localisation truth: a (signal, phase) pair shows the effect when, in some window of that phase, the noise-free
planted recording differs from the nominal twin by a noncentrality Σ (r / σ)² ≥ :data:`SHOWS` (σ: the planted
sensor noise combined with the twin's own spread, as the tool sees it), and does not when every window stays below
:data:`HIDDEN`; pairs in between are too faint to call either way and are left out of the F1 ("don't care"); the
table also gives the strict F1 that counts them as negatives.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from typing import Any

import numpy as np

from discrepancy.bench.synth import Synthetic
from discrepancy.pipeline import Diagnosis
from discrepancy.stats.locate import window_stats, windows

SHOWS, HIDDEN = 40.0, 10.0
TARGETS = {"top1": 0.90, "f1": 0.85, "param_error": 0.15, "coverage": 0.80, "reduction": 0.70, "double": 0.75,
           "null": 0.95, "ooc": 0.80}

Pair = tuple[str, str]


def truth_pairs(real: Synthetic, d: Diagnosis) -> tuple[set[Pair], set[Pair]]:
    """(pairs that show the effect, pairs too faint to call) on the analysed cycle."""
    runs = d.traces.get(real.clean.name)
    if runs is None or d.noise is None:
        return set(), set()
    twin = np.stack([runs["twin"].signals[s] for s in d.names], axis=1)
    clean = real.clean.matrix(d.names)
    sd = np.array([real.noise_sd.get(s, 0.0) for s in d.names])
    sigma = np.sqrt(sd[None, :] ** 2 + d.noise.twin**2)
    z = np.nan_to_num((clean - twin) / np.maximum(sigma, 1e-300), nan=1e3)
    wins = windows(real.clean.phases)
    lam = window_stats(z, wins)
    shows, faint = set(), set()
    for i, w in enumerate(wins):
        for j, s in enumerate(d.names):
            if lam[i, j] >= SHOWS:
                shows.add((s, w.phase))
            elif lam[i, j] >= HIDDEN:
                faint.add((s, w.phase))
    return shows, faint - shows


def _f1(tp: int, fp: int, fn: int) -> float:
    return 1.0 if tp + fp + fn == 0 else 2 * tp / (2 * tp + fp + fn)


def f1(result: dict[str, Any], strict: bool = False) -> float:
    truth = {tuple(p) for p in result["truth_pairs"]}
    skip = set() if strict else {tuple(p) for p in result["dont_care"]}
    found = {tuple(p) for p in result["located_pairs"]} - skip
    return _f1(len(found & truth), len(found - truth), len(truth - found))


def _median(values: Sequence[float]) -> float:
    return float(np.median(values)) if len(values) else float("nan")


def _mean(values: Sequence[float]) -> float:
    return float(np.mean(values)) if len(values) else float("nan")


def _fmt(x: float, pct: bool = True) -> str:
    if not np.isfinite(x):
        return "-"
    if not pct:
        return f"{x:.3g}"
    return f"{100 * x:.1f} %" if abs(x) < 0.1 else f"{100 * x:.0f} %"


def _met(key: str, value: float) -> str:
    """``yes``/``no`` against :data:`TARGETS` (time: ≤ 60 s), ``-`` when there is nothing to score."""
    if not np.isfinite(value):
        return "-"
    ok = value <= 60.0 if key == "time" else value <= TARGETS[key] if key == "param_error" else value >= TARGETS[key]
    return "yes" if ok else "no"


def single_rows(results: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Per planted effect (single-effect cases): n, top-1, name-only, F1, parameter error, coverage, reduction."""
    groups: dict[str, list[dict[str, Any]]] = defaultdict(list)
    hidden: dict[str, int] = defaultdict(int)
    for r in results:
        if r["kind"] == "single":
            name = r["matches"][0]["effect"]
            if r["truth_pairs"]:
                groups[name].append(r)
            else:  # the planted effect shows nowhere above noise: nothing to find
                hidden[name] += 1
                hidden["all"] += 1
    groups["all"] = [r for rs in list(groups.values()) for r in rs]
    rows = {}
    for name, rs in groups.items():
        m = [r["matches"][0] for r in rs]
        top1 = [bool(r["named"]) and r["named"][0][0] == x["effect"] and x["named"] for r, x in zip(rs, m, strict=True)]
        rows[name] = {
            "n": len(rs), "hidden": hidden[name], "top1": _mean(top1), "name_only": _mean([x["name_only"] for x in m]),
            "f1": _mean([f1(r) for r in rs]), "f1_strict": _mean([f1(r, strict=True) for r in rs]),
            "param_error": _median([x["param_error"] for x in m if "param_error" in x]),
            "coverage": _mean([x["covered"] for x in m if "covered" in x]),
            "reduction": _median([r["reduction"] for r in rs if r["reduction"] is not None]),
        }
    return rows


def summary(results: list[dict[str, Any]]) -> dict[str, float]:
    """Headline figures over all cases."""
    by = defaultdict(list)
    for r in results:
        by[r["kind"]].append(r)
    rows = single_rows(results)
    return {
        **{k: rows["all"][k] for k in ("top1", "f1", "param_error", "coverage", "reduction")},
        "double": _mean([all(m["named"] for m in r["matches"]) for r in by["double"]]),
        "null": _mean([not r["named"] for r in by["null"]]),
        "ooc": _mean([r["unexplained"] for r in by["ooc"]]),
        "diagnosis_median_s": _median([r["diagnosis_s"] for r in results]),
        "diagnosis_max_s": float(max((r["diagnosis_s"] for r in results), default=float("nan"))),
    }


def table(results: list[dict[str, Any]], header: str = "") -> str:
    """Markdown results: headline vs targets, per-effect rows, per-case list."""
    s = summary(results)
    counts = {k: sum(r["kind"] == k for r in results) for k in ("double", "null", "ooc")}
    counts["single"] = single_rows(results)["all"]["n"]
    head = ["| metric | result | target | met | cases |", "|---|---|---|---|---|"]
    lines = [header, "", *head] if header else head
    spec = [("single: top-1 identification", "top1", counts["single"]), ("single: localisation F1", "f1",
            counts["single"]), ("single: median parameter error", "param_error", counts["single"]),
            ("single: interval coverage", "coverage", counts["single"]), ("single: median residual reduction "
            "(held out)", "reduction", counts["single"]), ("two effects: both named", "double", counts["double"]),
            ("null: nothing named", "null", counts["null"]), ("out of catalogue: unexplained", "ooc", counts["ooc"])]
    for label, key, n in spec:
        cmp = "≤" if key == "param_error" else "≥"
        lines.append(f"| {label} | {_fmt(s[key])} | {cmp} {_fmt(TARGETS[key])} | {_met(key, s[key])} | {n} |")
    times = f"{s['diagnosis_median_s']:.1f} s / {s['diagnosis_max_s']:.1f} s"
    lines.append(f"| diagnosis time in this run, median / max | {times} | ≤ 60 s | {_met('time', s['diagnosis_max_s'])}"
                 " | all |")
    lines += ["", "Per planted effect (single-effect cases; an effect planted so faint that it shows in no "
              "signal × phase (noncentrality < 40 everywhere) is not scored and counted in brackets):", "",
              "| effect | n (+ too faint) | top-1 | name only | F1 (strict) | median param. error | coverage | "
              "median reduction |", "|---|---|---|---|---|---|---|---|"]
    for name, row in sorted(single_rows(results).items(), key=lambda kv: (kv[0] == "all", kv[0])):
        lines.append(f"| {name} | {row['n']} (+{row['hidden']}) | {_fmt(row['top1'])} | {_fmt(row['name_only'])} | "
                     f"{row['f1']:.2f} ({row['f1_strict']:.2f}) | {_fmt(row['param_error'])} | "
                     f"{_fmt(row['coverage'])} | {_fmt(row['reduction'])} |")
    cut = [r for r in results if (r.get("budget") or {}).get("cut")]
    lines += ["", f"Search cut short by its budget in {len(cut)} of {len(results)} cases "
              f"({', '.join(sorted({r['budget']['cut'] for r in cut})) or 'none'}).", "",
              "Cases (time: the diagnosis alone, load: 1-min load average when it ended):", "",
              "| # | kind | scale | soil | noise | planted | named | replays | cut | load | time [s] |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        planted = ", ".join(r["planted"]) or (f"{r['ooc']} (out of catalogue)" if r["ooc"] else "-")
        named = ", ".join(f"{n}[{t}]" if t else n for n, t in r["named"]) or "-"
        b, load = r.get("budget") or {}, r.get("load")
        lines.append(f"| {r['index']} | {r['kind']} | {r['scale']} | {r['soil']} | {r['noise']:g} | {planted} | "
                     f"{named} | {r.get('simulations', '-')} | {b.get('cut') or '-'} | "
                     f"{'-' if load is None else f'{load:.1f}'} | {r['diagnosis_s']:.1f} |")
    return "\n".join(lines) + "\n"
