"""The streaming path for a live twin: push target rows one at a time; the GRU's hidden state is carried.

    model = zoo.load("gru-eq10")
    with model.stream(on_prediction=print, rerun="scaling.rrd") as s:   # or rerun="spawn" for a live viewer
        for row in twin_rows():                                        # {"F31": ..., "x_b [mm]": ..., ...}
            p = s.push(row)                                            # p.force, p.lower, p.upper (N)

Rows are mappings (``name`` in SI or ``name [unit]``; the key layout is resolved once and cached) or sequences
of SI floats in ``model.target_variables`` order. A callback, if given, receives every :class:`Prediction`. With
``rerun`` the predictions are logged as scalars (timeline ``step``) to a rerun recording: a ``.rrd`` path, the
string ``"spawn"`` (a local viewer), ``"connect"`` (a viewer already running on this machine: rerun's default
loopback address) or an open :class:`rerun.RecordingStream`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from zoo.serving.inputs import InputError, column_plan

if TYPE_CHECKING:
    import rerun as rr

APP_ID = "scaletwin-serving"


class RowModel(Protocol):
    """What a :class:`Stream` serves: a model that scales one SI row at a time, such as
    :class:`~zoo.serving.model.ScalingModel` (the stream needs nothing else of it)."""

    @property
    def name(self) -> str: ...  # the model's name (the rerun recording's)

    variable: str  # the scaled force, e.g. "F21"
    target_variables: tuple[str, ...]  # a row's SI values, in this order

    def row(self, x: Sequence[float], state: Any, source: Sequence[float] | None = None
            ) -> tuple[float, float, float, float, bool, Any]:
        """(force, lower, upper, δ1, extrapolated, next state) for one SI row (``state``: the recurrent state)."""
        ...


@dataclass(frozen=True)
class Prediction:
    """One streamed prediction: ``force`` with ``lower``/``upper`` (SI, e.g. N), δ1, the extrapolation flag and
    the ``step`` (0-based count of rows pushed since the last reset)."""

    force: float
    lower: float
    upper: float
    delta1: float
    extrapolated: bool
    step: int


class Stream:
    """Row-by-row serving of one :class:`RowModel`, e.g. a :class:`~zoo.serving.model.ScalingModel` (see the
    module docstring)."""

    def __init__(self, model: RowModel, *, on_prediction: Callable[[Prediction], Any] | None = None,
                 rerun: Any = None) -> None:
        self.model = model
        self.on_prediction = on_prediction
        self._rec, self._own_rec = _recording(rerun, model.name)
        self._plans: dict[tuple[str, ...], tuple[list[str], list[float]]] = {}
        self.reset()

    def reset(self) -> None:
        """Start a new sequence: zero hidden state, step 0."""
        self.state: Any = None
        self.step = 0

    def push(self, row: Mapping[str, Any] | Sequence[float] | np.ndarray,
             source: Sequence[float] | np.ndarray | None = None) -> Prediction:
        """Predict one target row (the next time step of the sequence); see the module docstring for ``row``.

        ``source``: this row's own source row as SI floats in ``model.source_variables`` order (e.g. its matched
        row, for a model fitted with ``include_source=True``); default the model's bound source.
        """
        x = self._values(row)
        src = None if source is None else [float(v) for v in source]
        force, lo, hi, delta, outside, self.state = self.model.row(x, self.state, src)
        pred = Prediction(force, lo, hi, delta, outside, self.step)
        self.step += 1
        if self._rec is not None:
            self._log(pred)
        if self.on_prediction is not None:
            self.on_prediction(pred)
        return pred

    def close(self) -> None:
        """Flush and close a rerun recording this stream opened."""
        if self._rec is not None and self._own_rec:
            self._rec.flush()
            self._rec.disconnect()
        self._rec = None

    def __enter__(self) -> Stream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _values(self, row: Mapping[str, Any] | Sequence[float] | np.ndarray) -> list[float]:
        if not isinstance(row, Mapping):
            values = [float(v) for v in row]
            if len(values) != len(self.model.target_variables):
                raise InputError(f"a row needs {len(self.model.target_variables)} SI values "
                                 f"({', '.join(self.model.target_variables)}), got {len(values)}")
            return values
        keys = tuple(row)
        plan = self._plans.get(keys)
        if plan is None:
            idx, factor = column_plan(list(keys), self.model.target_variables, what=f"row {self.step}")
            plan = self._plans[keys] = ([keys[i] for i in idx], [float(f) for f in factor])
        try:
            return [float(row[k]) * f for k, f in zip(*plan, strict=True)]
        except (TypeError, ValueError) as exc:
            raise InputError(f"row {self.step}: non-numeric value ({exc})") from exc

    def _log(self, pred: Prediction) -> None:
        import rerun as rr

        assert self._rec is not None
        v = self.model.variable
        self._rec.set_time("step", sequence=pred.step)
        self._rec.log(f"{v}/predicted", rr.Scalars(pred.force))
        self._rec.log(f"{v}/lower", rr.Scalars(pred.lower))
        self._rec.log(f"{v}/upper", rr.Scalars(pred.upper))
        self._rec.log(f"{v}/extrapolated", rr.Scalars(float(pred.extrapolated)))


def _recording(rerun: Any, name: str) -> tuple[rr.RecordingStream | None, bool]:
    """(recording stream, whether this stream owns it) for the ``rerun`` argument of :class:`Stream`."""
    if rerun is None or rerun is False:
        return None, False
    import rerun as rr

    if isinstance(rerun, rr.RecordingStream):
        return rerun, False
    rec = rr.RecordingStream(APP_ID, recording_id=f"serving-{name}")
    if rerun == "spawn":
        rec.spawn()
    elif rerun == "connect":
        rec.connect_grpc()  # rerun's default address: the local (loopback) viewer
    elif isinstance(rerun, str | Path):
        Path(rerun).parent.mkdir(parents=True, exist_ok=True)
        rec.save(Path(rerun))
    else:
        raise ValueError(f"rerun must be None, a .rrd path, 'spawn', 'connect' or a RecordingStream, got {rerun!r}")
    rec.send_recording_name(f"serving {name}")
    return rec, True
