"""Every δ1 fit logged to rerun: an explicit :class:`rerun.RecordingStream` saved as ``fit.rrd`` beside the model.

Entities (timeline ``epoch``): ``/loss/train`` and ``/loss/validation`` (standardised loss per epoch; one series per
member for ensembles, ``/loss/member<k>/...``), then, static, ``/delta/predicted_vs_actual`` (held-out δ1 as
points) and ``/summary`` (the model's description and metrics as Markdown). Nothing global is touched: each call
opens and closes its own stream, so logging is safe from worker processes and tests.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr

from scaling.models import DeltaModel

APP_ID = "scaletwin-scaling"


def _losses(model: DeltaModel) -> dict[str, Any]:
    """Training logs by entity prefix: ``{"": log}`` for a single net, ``{"member0/": log, ...}`` for ensembles."""
    members = getattr(model, "members_", None)
    if members:
        return {f"member{i}/": m.log_ for i, m in enumerate(members) if getattr(m, "log_", None) is not None}
    log = getattr(model, "log_", None)
    return {"": log} if log is not None else {}


def log_fit(model: DeltaModel, path: str | Path, *, name: str, actual: np.ndarray | None = None,
            predicted: np.ndarray | None = None, metrics: Mapping[str, Any] | None = None) -> Path:
    """Write ``path`` (an ``.rrd`` file) with the loss curves, held-out δ1 and a summary of one fitted model."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(APP_ID, recording_id=f"{name}-{path.parent.name}")
    rec.save(path)
    rec.send_recording_name(name)
    for prefix, log in _losses(model).items():
        for i, value in enumerate(log.train_loss):
            rec.set_time("epoch", sequence=i)
            rec.log(f"loss/{prefix}train", rr.Scalars(float(value)))
        for i, value in enumerate(log.val_loss):
            rec.set_time("epoch", sequence=i)
            rec.log(f"loss/{prefix}validation", rr.Scalars(float(value)))
    if actual is not None and predicted is not None:
        pts = np.column_stack([np.asarray(actual, float), np.asarray(predicted, float)])
        pts = pts[np.isfinite(pts).all(axis=1)]
        rec.log("delta/predicted_vs_actual", rr.Points2D(pts, radii=0.002), static=True)
    text = f"# {name}\n\n```\n{model.describe()}\n```\n"
    if metrics:
        text += "\n| metric | value |\n|---|---|\n" + "".join(f"| {k} | {v} |\n" for k, v in metrics.items())
    rec.log("summary", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)
    rec.flush()
    rec.disconnect()
    return path


def log_figures(figures: Mapping[str, str | Path], path: str | Path, *, name: str = "figures") -> Path:
    """Write ``path`` (``.rrd``) with every PNG of ``figures`` as a static image under ``/figures/<key>``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(APP_ID, recording_id=f"{name}-{path.parent.name}")
    rec.save(path)
    rec.send_recording_name(name)
    for key, png in figures.items():
        rec.log(f"figures/{key}", rr.EncodedImage(path=Path(png)), static=True)
    rec.flush()
    rec.disconnect()
    return path
