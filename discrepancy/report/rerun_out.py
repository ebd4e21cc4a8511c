"""A rerun recording of a diagnosis: real, twin and corrected traces overlaid per signal, on the ``sim_time``
timeline, with the located windows as a text log; one view per signal in the stored blueprint."""

from __future__ import annotations

from pathlib import Path

import rerun as rr
import rerun.blueprint as rrb

from discrepancy.data.episode import EpisodeData
from discrepancy.pipeline import Diagnosis

APP_ID = "scaletwin_discrepancy"
SERIES = {"real": (0, 0, 0), "twin": (31, 119, 180), "corrected": (255, 127, 14)}


def blueprint(names: list[str]) -> rrb.Blueprint:
    """Tabs of time-series views (one per signal, real/twin/corrected overlaid) and the located-window log."""
    views = [rrb.TimeSeriesView(origin=f"/signals/{s}", name=s) for s in names]
    return rrb.Blueprint(rrb.Horizontal(rrb.Tabs(*views), rrb.TextLogView(origin="/located", name="located"),
                                        column_shares=[3, 1]), collapse_panels=True)


def _log_episode(rec: rr.RecordingStream, d: Diagnosis, ep: EpisodeData, names: list[str]) -> None:
    runs = d.traces.get(ep.name, {})
    for s in names:
        for series, color in SERIES.items():
            rec.log(f"/signals/{s}/{series}", rr.SeriesLines(colors=[color], names=[series]), static=True)
    for k, t in enumerate(ep.time):
        rec.set_time("sim_time", duration=float(t))
        for s in names:
            rec.log(f"/signals/{s}/real", rr.Scalars(float(ep.signals[s][k])))
            for series in ("twin", "corrected"):
                if series in runs:
                    rec.log(f"/signals/{s}/{series}", rr.Scalars(float(runs[series].signals[s][k])))


def write_rrd(d: Diagnosis, path: str | Path, held_out: bool = True) -> Path:
    """Save the recording to ``path`` (the held-out cycle when there is one, else the analysed one)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    names = list(d.names)
    rec = rr.RecordingStream(APP_ID)
    rec.save(str(path), default_blueprint=blueprint(names))
    ep = d.held_out[0] if held_out and d.held_out else d.train
    _log_episode(rec, d, ep, names)
    for loc in d.located:
        rec.set_time("sim_time", duration=loc.t_start)
        rec.log("/located", rr.TextLog(f"{loc.signal} in {loc.phase}: effect size {loc.effect_size:.3g}, "
                                       f"p = {loc.p_value:.2e}", level="WARN"))
    for e in d.effects:
        rec.log("/effects", rr.TextLog(f"{e.effect}[{e.target}] {e.parameters}"), static=True)
    rec.flush()
    rec.disconnect()
    return path
