"""Outputs of a diagnosis: the JSON document (validated against ``schemas/report.schema.json`` with
``jsonschema``), a Markdown report with plots, and the plain-text summary ``scaletwin diagnose`` prints. The rerun
recording is in :mod:`discrepancy.report.rerun_out`.

JSON::

    {"located": [{"signal", "phase", "t_start", "t_end", "effect_size", "p_value"}],
     "effects": [{"effect", "target", "parameters", "interval", "units", "confidence", "explained_fraction",
                  "confounded_with", "alternatives"}],
     "fit": {"held_out", "before": {signal: nrmse}, "after": {signal: nrmse}, "by_phase": {signal: {phase: [b, a]}},
             "normaliser": {signal: spread}, "scale": {signal: rms}, "flags": {signal: [flag]},
             "phase_flags": {signal: {phase: [flag]}}, "worse_overall"},
     "search": {"replay_budget", "time_budget_s", "replays", "cut", "cut_at_s"},  # only when the search was cut
     "drift": [signal]}  # only when what was located is put down to those sensors' drift

``p_value`` is Benjamini–Hochberg adjusted; ``parameters``/``interval`` hold each SI parameter and its
dimensionless group as ``pi_<parameter>``, ``units`` the SI unit of each parameter. ``confidence`` is a named
effect's likelihood weight exp(−ΔJ/2) among all trials of its round, null on ``unexplained``;
``explained_fraction`` the share of the excess residual left before its round that the effect (on
``unexplained``: the closest candidate) removes; ``alternatives`` the effect labels the recording cannot tell apart
from it. ``fit`` is on
held-out cycles when ``held_out``; a ``flags`` entry ("worse", "normaliser near zero") marks an NRMSE not to be
trusted as an improvement (:func:`discrepancy.search.fit.entry_flags`), and ``worse_overall`` says the correction
made the comparison worse as a whole. ``search`` is there only when the search budget
(:mod:`discrepancy.search.budget`) cut the search short (``cut``: "replays" or "time").
"""

from __future__ import annotations

import json
import math
import shutil
import textwrap
from pathlib import Path
from typing import Any

from discrepancy.effects import CATALOGUE, UNEXPLAINED
from discrepancy.pipeline import Diagnosis, ReportedEffect
from discrepancy.report.schema import validate
from discrepancy.search.fit import WORSE, Comparison
from scaletwin_envs.signal_units import SIGNAL_UNITS

MAX_LOCATED_ROWS = 40
TOP_SIGNALS = 6  # signals the text summary lists besides the flagged ones
NONE = "—"  # shown where a value does not apply (the confidence of ``unexplained``)


def _number(x: float) -> float:
    """A JSON number: NaN becomes 0, ±infinity the largest float of that sign."""
    if math.isnan(x):
        return 0.0
    return float(x) if math.isfinite(x) else math.copysign(1e308, x)


def _unit_fraction(x: float | None) -> float | None:
    return None if x is None else float(min(max(_number(x), 0.0), 1.0))


def units(e: ReportedEffect) -> dict[str, str]:
    """SI unit of each parameter of ``e`` (a sensor bias takes its signal's unit; empty for ``unexplained``)."""
    if e.effect not in CATALOGUE:
        return {}
    spec = CATALOGUE[e.effect]
    known = {p.name for p in spec.params}
    out = {k: spec.unit(k, e.target) for k in e.parameters if k in known}
    return {k: SIGNAL_UNITS.get(e.target or "", u) if u == "signal unit" else u for k, u in out.items()}


def _pi_interval(e: ReportedEffect, k: str) -> tuple[float, float] | None:
    """The interval of ``pi_<k>``: the SI interval over the same unit (None without a group)."""
    pi = e.groups.get(f"pi_{k}")
    if not pi or k not in e.interval:
        return None
    unit = e.parameters[k] / pi
    a, b = sorted(v / unit for v in e.interval[k])
    return a, b


def _effect_json(e: ReportedEffect) -> dict[str, Any]:
    params = {k: _number(v) for k, v in e.parameters.items()}
    params.update({k: _number(v) for k, v in e.groups.items()})
    interval = {k: [_number(a), _number(b)] for k, (a, b) in e.interval.items()}
    for k in e.interval:
        if (pi := _pi_interval(e, k)) is not None:
            interval[f"pi_{k}"] = [_number(pi[0]), _number(pi[1])]
    return {"effect": e.effect, "target": e.target, "parameters": params, "interval": interval, "units": units(e),
            "confidence": _unit_fraction(e.confidence), "explained_fraction": _unit_fraction(e.explained_fraction),
            "confounded_with": list(e.confounded_with), "alternatives": list(e.alternatives),
            "separated_by": [a.to_dict() for a in e.separated_by]}


def _fit_json(c: Comparison) -> dict[str, Any]:
    return {
        "held_out": bool(c.held_out),
        "before": {k: _number(v) for k, v in c.before.items()},
        "after": {k: _number(v) for k, v in c.after.items()},
        "by_phase": {s: {p: [_number(b), _number(a)] for p, (b, a) in ph.items()} for s, ph in c.by_phase.items()},
        "normaliser": {k: _number(v) for k, v in c.normaliser.items()},
        "scale": {k: _number(v) for k, v in c.scale.items()},
        "flags": c.flagged,
        "phase_flags": c.phase_flagged,
        "worse_overall": bool(c.worse_overall),
    }


def to_json(d: Diagnosis) -> dict[str, Any]:
    """The diagnosis as the report document (validated)."""
    doc = {
        "located": [loc.to_dict() for loc in d.located],
        "effects": [_effect_json(e) for e in d.effects],
        "fit": _fit_json(d.comparison),
    }
    if d.budget is not None and d.budget.cut:  # only then: an uncut report keeps the three keys
        doc["search"] = d.budget.to_dict()
    if d.train.input_report is not None:  # a log read from a file: what was done to it
        doc["input"] = d.train.input_report.to_dict()
    if d.alignment is not None:
        doc["alignment"] = d.alignment.to_dict()
    if d.start_check is not None:  # only for a log without seed whose twin left windows located
        doc["start_check"] = d.start_check.to_dict()
    if d.identification.drift:  # only then: what was located is put down to the sensors' drift
        doc["drift"] = list(d.identification.drift)
    validate(doc)
    return doc


def write_json(d: Diagnosis, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(to_json(d), indent=2))
    return path


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def _where(c: Comparison) -> str:
    return "the held-out cycles" if c.held_out else "the analysed cycle (no held-out cycle given)"


def _flagged_pair(c: Comparison, s: str) -> str:
    flags = c.flags(s)
    return f"{s} {_fmt(c.before[s])} → {_fmt(c.after[s])}" + (f" ({', '.join(flags)})" if flags else "")


def warnings(d: Diagnosis) -> list[str]:
    """What to say at the top, next to the effects: a comparison that got worse overall, or signals that did."""
    c = d.comparison
    if not d.effects or not c.before:
        return []
    worse = c.worse
    if c.worse_overall:
        return [f"WARNING: the correction made the fit worse on {_where(c)} (sum over signals of RMS residual / "
                f"scale {_fmt(c.residual(False))} → {_fmt(c.residual(True))}); the effects below are not confirmed "
                "by it." + (f" Worse: {'; '.join(_flagged_pair(c, s) for s in worse)}." if worse else "")]
    if worse:
        return [f"Note: {len(worse)} signal(s) fit worse after the correction on {_where(c)}: "
                f"{'; '.join(_flagged_pair(c, s) for s in worse)}."]
    return []


def _confidence(e: ReportedEffect) -> str:
    return NONE if e.confidence is None else f"{e.confidence:.2f}"


def _explained(e: ReportedEffect) -> str:
    return NONE if e.explained_fraction is None else f"{e.explained_fraction:.2f}"


def effect_lines(e: ReportedEffect) -> tuple[str, list[str]]:
    """A heading and the lines of one effect: full target, parameters with 95 % intervals and units, confidence,
    explained fraction, and the full labels of its rivals and of what the recording cannot tell apart from it."""
    if e.effect == UNEXPLAINED:
        title = UNEXPLAINED + (f", shows most on {e.target}" if e.target else "")
        lines = [f"confidence {NONE} (nothing is named)",
                 f"explained fraction {_explained(e)} (of the excess residual, by the closest candidate)"]
        if e.confounded_with:
            lines.append("closest candidates (none is found): " + ", ".join(e.confounded_with))
    else:
        title = e.effect + (f" on {e.target}" if e.target else " (no target)")
        u = units(e)
        lines = []
        for k, v in e.parameters.items():
            text = f"{k} = {_fmt(v)} {u.get(k, '')}".rstrip()
            if k in e.interval:
                a, b = e.interval[k]
                text += f", 95 % interval [{_fmt(a)}, {_fmt(b)}]"
            if (pi := e.groups.get(f"pi_{k}")) is not None:
                text += f"; pi_{k} = {_fmt(pi)}"
                if (pin := _pi_interval(e, k)) is not None:
                    text += f" [{_fmt(pin[0])}, {_fmt(pin[1])}]"
            lines.append(text)
        lines += [f"confidence {_confidence(e)} (likelihood weight exp(−ΔJ/2) among all trials of its round)",
                  f"explained fraction {_explained(e)} (of the excess residual left before it)"]
        if e.confounded_with:
            lines.append("confounded with: " + ", ".join(e.confounded_with))
    if e.alternatives:
        lines.append("cannot be told apart from: " + ", ".join(e.alternatives))
        for a in e.separated_by:
            where = "in this log" if a.in_log else "not in this log"
            lines.append(f"  {a.label}: objective +{a.delta_objective:.1f}; {a.channel} ({where}) separates them "
                         f"best ({a.separation:.1f} noise SD apart)")
    return title, lines


def _comparison_lines(c: Comparison, top: int = TOP_SIGNALS) -> list[str]:
    """NRMSE before → after of the flagged signals and the ``top`` largest, flagged phase entries that got worse,
    and how many phase entries divide by a near-zero spread."""
    flagged = c.flagged
    order = sorted(c.before, key=lambda s: -c.before[s])
    shown = [s for s in order if s in flagged] + [s for s in order[:top] if s not in flagged]
    lines = [f"NRMSE (RMS residual / spread of the real signal) on {_where(c)}, before → after:"]
    lines += [f"  {_flagged_pair(c, s)}" for s in shown]
    phases = c.phase_flagged
    lines += [f"  {s} in {p} {_fmt(c.by_phase[s][p][0])} → {_fmt(c.by_phase[s][p][1])} ({', '.join(f)})"
              for s, ph in phases.items() for p, f in ph.items() if WORSE in f]
    near = sum(1 for ph in phases.values() for f in ph.values() if WORSE not in f)
    if near:
        lines.append(f"  ({near} per-phase entries divide by a spread near zero and are not judged)")
    return lines


def _wrap(line: str, width: int) -> list[str]:
    """Wrap at spaces only (labels and targets are never cut), continuing lines indented."""
    indent = line[: len(line) - len(line.lstrip())]
    return textwrap.wrap(line, width=max(width, 40), subsequent_indent=indent + "    ", break_long_words=False,
                         break_on_hyphens=False) or [""]


def input_notes(d: Diagnosis) -> list[str]:
    """What was done to the log before comparing: resampling, bridged gaps, missing channels, estimated start,
    sensor filter and time offset."""
    out = []
    rep = d.train.input_report
    if rep is not None:
        if rep.resampled:
            out.append(f"Log sampled at {rep.original_rate_hz:.4g} Hz, resampled to the twin's control step "
                       f"({rep.control_dt:.4g} s) with an anti-aliasing filter.")
        out += [f"Gap in {ch} from {a:.3g} s to {b:.3g} s bridged." for ch, a, b in rep.gaps]
        if rep.channels_missing:
            out.append("Channels not in the log: " + ", ".join(rep.channels_missing) + " (effects they would tell "
                       "apart are listed as alternatives).")
        out += list(rep.warnings)
    if d.alignment is not None:
        out += [n[0].upper() + n[1:] + "." for n in d.alignment.notes]
    if (c := d.start_check) is not None:
        pile = (f"pile {c.options.get('pile_distance', math.nan):.3g} boom lengths away, repose angle "
                f"{math.degrees(c.options.get('repose_angle', math.nan)):.3g}°, {c.pile_shift:.2g} half-ranges of "
                "the env's draw from the twin's pile")
        if c.cleared:
            effects = [x for x in c.indistinguishable if x != UNEXPLAINED]
            found = ""
            if effects:
                found = (f" Against the early-dig start the search reached {', '.join(effects)}: this log cannot tell "
                         f"{'it' if len(effects) == 1 else 'them'} from that pile.")
            elif c.indistinguishable:
                found = " Against the early-dig start the search found no catalogue effect for it (unexplained)."
            left = "none" if c.located_after == 0 else f"only {c.located_after} faint (put down to chance)"
            verb = "is" if c.located_before == 1 else "are"
            out.append(f"Against the start fitted on the early dig {_windows(c.located_before)} {verb} located; a "
                       f"start refitted on the whole log ({pile}) leaves {left}: the log is consistent with the twin, "
                       f"whose pile a log without seed does not pin down, so nothing is named.{found}")
        else:
            out.append(f"Against a start refitted on the whole log ({pile}) {c.located_after} windows stay located "
                       f"({c.located_before} against the twin's start): the pile alone does not explain them.")
    return out


def _start(d: Diagnosis) -> str:
    """How the twin starts: from the log's reset seed, or (a log without one) from a start estimated from the log."""
    if d.twin.start:
        return "start pose and pile estimated from the log (it has no reset seed)"
    return f"reset seed {d.twin.seed}"


def _windows(n: int) -> str:
    return f"{n} window" + ("" if n == 1 else "s")


def text_report(d: Diagnosis, width: int | None = None) -> str:
    """The summary ``scaletwin diagnose`` prints: warnings first, then one block per effect, then the flagged
    comparison; lines wrapped at ``width`` (default: the terminal's) without cutting a name."""
    width = width or shutil.get_terminal_size((100, 24)).columns
    cut = f", search cut short by its {d.budget.cut} budget" if d.budget and d.budget.cut else ""
    lines = [f"{d.train.name}: {len(d.located)} located windows, {d.simulations} twin replays, "
             f"{d.timings.get('total', 0.0):.1f} s{cut}"]
    lines += ["", warning] if (warning := " ".join(warnings(d))) else []
    lines += ["", *input_notes(d)] if input_notes(d) else []
    if not d.effects:
        lines += ["", "No effect named: " + _nothing_named(d)]
    for k, e in enumerate(d.effects, 1):
        title, body = effect_lines(e)
        lines += ["", f"{k}. {title}", *(f"   {b}" for b in body)]
    lines += ["", *_comparison_lines(d.comparison)]
    return "\n".join(w for line in lines for w in _wrap(line, width)) + "\n"


def _nothing_named(d: Diagnosis) -> str:
    """Why a diagnosis that names nothing names nothing (it located nothing, the sensors' drift explains what it
    located, or a few faint windows are put down to chance)."""
    if d.start_check is not None and d.start_check.cleared:
        return ("what was located is the pile's (a start refitted on the whole log leaves nothing located but what "
                "is put down to chance; a log without seed does not pin its pile down).")
    if not d.located:
        return "nothing differs beyond noise."
    if d.identification.drift:
        return (f"what was located on {', '.join(d.identification.drift)} is put down to those sensors' drift "
                "(whitened with the drift estimated on the record, nothing is left; no catalogue effect explains "
                "it).")
    return "a few faint windows no candidate explains (put down to chance)."


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header), *("| " + " | ".join(r) + " |" for r in rows)]


def _effects_section(d: Diagnosis) -> list[str]:
    """Warnings, then one sub-section per effect (full targets and labels, intervals and units)."""
    out = [f"**{w}**" for w in warnings(d)]
    out += [""] if out else []
    if not d.effects:
        return [*out, "No effect is named: " + _nothing_named(d)]
    for k, e in enumerate(d.effects, 1):
        title, body = effect_lines(e)
        out += [f"### {k}. {title}", "", *(f"- {b}" for b in body), ""]
    return out


def _fit_section(d: Diagnosis) -> list[str]:
    c = d.comparison
    order = sorted(c.before, key=lambda s: -c.before[s])

    def phase(s: str, p: str, b: float, a: float) -> str:
        flags = c.flags(s, p)
        return f"{p} {_fmt(b)}→{_fmt(a)}" + (f" ({', '.join(flags)})" if flags else "")

    rows = [[s, _fmt(c.before[s]), _fmt(c.after[s]), ", ".join(c.flags(s)) or "-",
             "; ".join(phase(s, p, b, a) for p, (b, a) in c.by_phase.get(s, {}).items())] for s in order]
    return [f"NRMSE (RMS residual / spread of the real signal) on {_where(c)}, before and after the correction. "
            f"*worse*: the correction raised it; *normaliser near zero*: the spread it divides by is below 1 % of "
            "the signal's size, so the ratio says little.", "",
            *_table(["signal", "before", "after", "flags", "per phase (before→after)"], rows)]


def markdown(d: Diagnosis, plots: list[str] | None = None) -> str:
    """The Markdown report (``plots``: image paths relative to the report)."""
    lines = [f"# Discrepancy diagnosis: {d.train.name}", "",
             f"Twin: {d.twin.loader.name}, soil {d.twin.soil.name}, {_start(d)}; {len(d.train)} control steps "
             f"of {d.train.dt:.4g} s; {len(d.held_out)} held-out cycle(s); {d.simulations} twin replays.", "",
             "## Named effects", "", *_effects_section(d), ""]
    if UNEXPLAINED in d.named:
        lines += ["The catalogue does not explain the residual (`unexplained`): the closest candidates are listed; "
                  "none is reported as found.", ""]
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
        from discrepancy.report.plots import save_plots  # matplotlib, loaded only when plotting

        plots = [p.name for p in save_plots(d, path.with_suffix(""))]
    path.write_text(markdown(d, plots))
    return path
