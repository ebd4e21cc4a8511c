"""Outputs of a diagnosis: the JSON document (validated against ``schemas/report.schema.json``) and a Markdown
report with plots. The rerun recording is in :mod:`discrepancy.report.rerun_out`.

JSON::

    {"located": [{"signal", "phase", "t_start", "t_end", "effect_size", "p_value"}],
     "effects": [{"effect", "target", "parameters", "interval", "confidence", "confounded_with"}],
     "fit": {"before": {signal: nrmse}, "after": {signal: nrmse}},
     "search": {"replay_budget", "time_budget_s", "replays", "cut", "cut_at_s"}}  # only when the search was cut

``p_value`` is Benjamini–Hochberg adjusted; ``parameters``/``interval`` hold each SI parameter and its
dimensionless group as ``pi_<parameter>``; ``fit`` is on held-out cycles when there were any; ``search`` is there
only when the search budget (:mod:`discrepancy.search.budget`) cut the search short (``cut``: "replays" or "time").
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from discrepancy.effects import CATALOGUE
from discrepancy.pipeline import Diagnosis, ReportedEffect
from discrepancy.report.schema import validate

MAX_LOCATED_ROWS = 40


def _number(x: float) -> float:
    return float(x) if math.isfinite(x) else 0.0


def _effect_json(e: ReportedEffect) -> dict[str, Any]:
    params = {k: _number(v) for k, v in e.parameters.items()}
    params.update({k: _number(v) for k, v in e.groups.items()})
    interval = {k: [_number(a), _number(b)] for k, (a, b) in e.interval.items()}
    for k, (a, b) in e.interval.items():
        unit = e.parameters[k] / e.groups[f"pi_{k}"] if e.groups.get(f"pi_{k}") else None
        if unit:
            interval[f"pi_{k}"] = sorted([_number(a / unit), _number(b / unit)])
    return {"effect": e.effect, "target": e.target, "parameters": params, "interval": interval,
            "confidence": float(min(max(e.confidence, 0.0), 1.0)), "confounded_with": list(e.confounded_with)}


def to_json(d: Diagnosis) -> dict[str, Any]:
    """The diagnosis as the report document (validated)."""
    doc = {
        "located": [loc.to_dict() for loc in d.located],
        "effects": [_effect_json(e) for e in d.effects],
        "fit": {"before": {k: _number(v) for k, v in d.comparison.before.items()},
                "after": {k: _number(v) for k, v in d.comparison.after.items()}},
    }
    if d.budget is not None and d.budget.cut:  # only then: an uncut report keeps the three keys
        doc["search"] = d.budget.to_dict()
    validate(doc)
    return doc


def write_json(d: Diagnosis, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(to_json(d), indent=2))
    return path


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header), *("| " + " | ".join(r) + " |" for r in rows)]


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def _effects_section(d: Diagnosis) -> list[str]:
    if not d.effects:
        return ["Nothing differs beyond noise: no effect is named."]
    rows = []
    for e in d.effects:
        units = {k: CATALOGUE[e.effect].unit(k, e.target) for k in e.parameters} if e.effect in CATALOGUE else {}
        params = ", ".join(f"{k} = {_fmt(v)} {units.get(k, '')} [{_fmt(e.interval[k][0])}, {_fmt(e.interval[k][1])}]"
                           for k, v in e.parameters.items())
        groups = ", ".join(f"{k} = {_fmt(v)}" for k, v in e.groups.items())
        rows.append([e.effect, e.target or "-", params or "-", groups or "-", f"{e.confidence:.2f}",
                     ", ".join(e.confounded_with) or "-"])
    return _table(["effect", "target", "parameters (SI) [95 % interval]", "dimensionless groups", "confidence",
                   "confounded with"], rows)


def _fit_section(d: Diagnosis) -> list[str]:
    c = d.comparison
    where = "held-out cycles" if c.held_out else "the analysed cycle (no held-out cycle given)"
    order = sorted(c.before, key=lambda s: -c.before[s])
    rows = [[s, _fmt(c.before[s]), _fmt(c.after[s]),
             "; ".join(f"{p} {_fmt(b)}→{_fmt(a)}" for p, (b, a) in c.by_phase.get(s, {}).items())] for s in order]
    return [f"NRMSE (RMS residual / spread of the real signal) on {where}, before and after the correction:", "",
            *_table(["signal", "before", "after", "per phase (before→after)"], rows)]


def markdown(d: Diagnosis, plots: list[str] | None = None) -> str:
    """The Markdown report (``plots``: image paths relative to the report)."""
    lines = [f"# Discrepancy diagnosis: {d.train.name}", "",
             f"Twin: {d.twin.loader.name}, soil {d.twin.soil.name}, seed {d.twin.seed}; {len(d.train)} control steps "
             f"of {d.train.dt:.4g} s; {len(d.held_out)} held-out cycle(s); {d.simulations} twin replays.", "",
             "## Named effects", "", *_effects_section(d), ""]
    if d.identification.unexplained:
        lines += ["The catalogue does not explain the residual (`unexplained`): the closest candidates are listed "
                  "under *confounded with*; none is reported as found.", ""]
    if d.budget is not None and d.budget.cut:
        b = d.budget
        why = (f"{b.replays} twin replays" if b.cut == "replays" else
               f"{b.seconds:g} s of wall time (the result may depend on the machine's speed)")
        lines += [f"**The search was cut short** after {b.cut_at or 0.0:.1f} s by its budget of {why}; what it had "
                  "not explained by then is reported as `unexplained`.", ""]
    lines += ["## Where the twin and the machine differ", "",
              f"{len(d.located)} signal × window tests significant at FDR {0.01:g} (BH-adjusted p-values).", ""]
    rows = [[loc.signal, loc.phase, f"{loc.t_start:.2f}–{loc.t_end:.2f}", _fmt(loc.effect_size), f"{loc.p_value:.2e}"]
            for loc in d.located[:MAX_LOCATED_ROWS]]
    lines += _table(["signal", "phase", "time [s]", "effect size", "p (BH)"], rows) if rows else ["(none)"]
    lines += ["", "## Linkage redundancy", "", *_table(
        ["identity", "kind", "RMS disagreement (SI)", "p-value", "verdict"],
        [[c.identity.name, "algebraic" if c.identity.algebraic else "route 2", _fmt(c.rms), f"{c.p_value:.2e}",
          "broken" if c.broken else "holds"] for c in d.redundancy]), "",
              "A broken algebraic identity points at a sensor; a broken route-2 identity at a sensor or a torque in a "
              "hinge (friction, damping).", "", "## Before and after", "", *_fit_section(d), ""]
    lines += [f"![{Path(p).stem}]({p})" for p in plots or []]
    lines += ["", "## Time per step", "", *_table(["step", "s"], [[k, f"{v:.2f}"] for k, v in d.timings.items()])]
    return "\n".join(lines) + "\n"


def write_markdown(d: Diagnosis, path: str | Path, with_plots: bool = True) -> Path:
    """Write the report and its plots (PNG files beside it)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    plots: list[str] = []
    if with_plots:
        from discrepancy.report.plots import save_plots

        plots = [p.name for p in save_plots(d, path.with_suffix(""))]
    path.write_text(markdown(d, plots))
    return path


def top_signals(d: Diagnosis, n: int = 6) -> list[str]:
    """The signals with the largest residual before the correction."""
    order = sorted(d.comparison.before, key=lambda s: -d.comparison.before[s])
    return [s for s in order if np.isfinite(d.comparison.before[s])][:n]
