"""Input conditions of the benchmark: how a case's recording reaches the tool.

* ``native``: an in-memory :class:`~discrepancy.data.episode.EpisodeData` at the twin's control step, with the
  reset seed and the machine in its provenance (as the benchmark always did).
* every other condition is a *field log*: a CSV file with ``name [unit]`` headers, some channels in non-SI units
  (:data:`LOG_UNITS`), no dig phases, no route-2 statics, and no reset seed (a data logger knows none); the twin is
  described by a JSON file without a seed. The tool reads it with its own loader
  (:func:`discrepancy.data.episode.load_episode`).

  * ``csv``: at the control step, nothing else changed (isolates the file format and the missing seed);
  * ``50hz``, ``200hz``, ``500hz``: logged at that rate: the truth between control steps is the planted twin's
    physics read at each of its soil refreshes (5 per control step, :func:`~discrepancy.bench.synth.simulate_between`)
    and interpolated cubically between those readings (before that: between the control steps alone, which put no
    relief or contact between them), commands are held over each control step, noise is added at the log's rate (so
    the tool must anti-alias);
  * ``offset``: at the control step, the signals shifted against the commands by ``offset_s`` (positive: the signals
    lag): the truth at the shifted times is the physics between the control steps, as for the fast logs (before
    2026-11-28: a cubic through the control samples, the very curve the tool's twin was read on at an offset);
    rows beyond the truth are dropped at the end, held at the start;
  * ``missing``: at the control step, one compared channel dropped.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline

from discrepancy.data.channels import COMPARED
from discrepancy.twin.spec import Between
from scaletwin_envs.recording.importer import to_si
from scaletwin_envs.recording.schema import COMMAND_COLUMNS
from scaletwin_envs.signal_units import SIGNAL_UNITS

CONDITIONS = ("native", "csv", "50hz", "200hz", "500hz", "offset", "missing")
#: Log rates of the high-rate conditions, Hz (issue 14: data loggers at 50–1000 Hz).
RATES = {"50hz": 50.0, "200hz": 200.0, "500hz": 500.0}
#: Time offset between a log's signals and its commands, s (magnitude; the sign is drawn).
OFFSET_RANGE = (0.05, 0.5)
#: Units a data logger would write (non-SI where a field log typically is); every other channel stays SI.
LOG_UNITS: dict[str, str] = {
    "time": "ms", **{s: "kN" for s in ("F21", "F31", "Pf_tilt", "Pf_lift", "F21_x", "F21_z", "F31_x", "F31_z",
                                       "R_x", "R_z")},
    "p_lift": "bar", "p_tilt": "bar", "x_b": "mm", "y_b": "mm", "lift_extension": "mm", "tilt_extension": "mm",
    "lift_speed": "mm/s", "tilt_speed": "mm/s", "boom_angle": "deg", "bucket_pitch": "deg", "travel_speed": "km/h",
    "m_b": "t", "m_load": "t",
}
#: Significant digits written to the CSV: far below any noise level drawn (≥ 0.2 % of range).
DIGITS = 10


@dataclass(frozen=True)
class Condition:
    """How a case's recordings are delivered.

    Attributes:
        name: one of :data:`CONDITIONS`.
        rate_hz: log rate, Hz (None: the twin's control step).
        offset_s: signals' delay behind the commands, s (negative: the signals lead).
        missing: the compared channel dropped from the log, or None.
    """

    name: str = "native"
    rate_hz: float | None = None
    offset_s: float = 0.0
    missing: str | None = None

    @property
    def field_log(self) -> bool:
        """Whether the recording is written as a CSV field log (no seed, no phases)."""
        return self.name != "native"

    def describe(self) -> str:
        extra = (f" {self.offset_s:+.2f} s" if self.offset_s else "") + (f" -{self.missing}" if self.missing else "")
        return f"{self.name}{extra}"


def draw_condition(rng: np.random.Generator, name: str, droppable: tuple[str, ...]) -> Condition:
    """A :class:`Condition` ``name`` with its parameters drawn from ``rng`` (``droppable``: channels that may go
    missing).

    Raises:
        ValueError: unknown condition.
    """
    if name not in CONDITIONS:
        raise ValueError(f"unknown input condition {name!r}; known {CONDITIONS}")
    if name == "offset":
        size = float(np.exp(rng.uniform(*np.log(OFFSET_RANGE))))
        return Condition(name, offset_s=size * float(rng.choice((-1.0, 1.0))))
    if name == "missing":
        return Condition(name, missing=str(rng.choice(droppable)))
    return Condition(name, rate_hz=RATES.get(name))


@dataclass
class LogData:
    """A log before noise: times (s), commands (rows, 3), true SI channels at those times, and the same channels at
    ``parts`` instants per log step (``fine``: the ``parts``-th of each group at the log's own time, the others
    evenly before it), which a sensor filter acts on (the signal between the samples, not a line through them)."""

    time: np.ndarray
    commands: np.ndarray
    truth: dict[str, np.ndarray]
    fine: dict[str, np.ndarray] = field(default_factory=dict)
    parts: int = 1

    @property
    def h(self) -> float:
        """Sampling step, s."""
        return float(np.median(np.diff(self.time)))


def resample(time: np.ndarray, commands: np.ndarray, signals: Mapping[str, np.ndarray], cond: Condition,
             control_dt: float, between: Between | None = None, parts: int = 1) -> LogData:
    """The true log of ``cond`` from a recording at the control step.

    Args:
        time: control-step times t_k = k·dt, s (t_k is the end of step k, where signals are sampled).
        commands: (steps, 3), command k held over (t_{k−1}, t_k].
        signals: SI channels at ``time``.
        cond: the condition (rate and offset are used here; dropping a channel is the writer's job).
        control_dt: the twin's control step, s.
        between: the same channels (every one of ``signals``) read between the control steps too (every
            ``between.dt`` s from the first at ``between.dt``): the truth is interpolated from those; None: from
            ``signals``.
        parts: instants per log step of :attr:`LogData.fine` (1: the log's own).
    """
    time = np.asarray(time, float)
    if between is None:
        splines = {k: CubicSpline(time, np.asarray(v, float)) for k, v in signals.items()}
        first = time[0]
    else:  # known from the first reading on, a fraction of a control step before the first sample
        fine = between.dt * np.arange(1, len(next(iter(between.signals.values()))) + 1)
        splines = {k: CubicSpline(fine, np.asarray(between.signals[k], float)) for k in signals}
        first = fine[0]
    if cond.rate_hz:
        h = 1.0 / cond.rate_hz
        t = time[0] + h * np.arange(int(np.floor((time[-1] - time[0]) / h + 1e-9)) + 1)
    else:
        t = time.copy()
    src = t - cond.offset_s  # the sensor reading logged at t is the truth at t − offset
    keep = src <= time[-1] + 1e-9
    t, src = t[keep], src[keep]
    step = np.clip(np.ceil(t / control_dt - 1e-6).astype(int) - 1, 0, len(commands) - 1)
    h = float(np.median(np.diff(t))) if len(t) > 1 else control_dt
    fine_src = (src[:, None] - h * (parts - 1 - np.arange(parts)) / parts).ravel()
    fine = {k: sp(np.clip(fine_src, first, time[-1])) for k, sp in splines.items()}
    if not cond.rate_hz and not cond.offset_s:  # the control-step samples themselves (a spline is exact to 1e-12)
        truth = {k: np.asarray(signals[k], float).copy() for k in splines}
    else:
        truth = {k: v[parts - 1::parts] for k, v in fine.items()}
    return LogData(t, np.asarray(commands, float)[step], truth, fine, parts)


def write_csv(path: Path, time: np.ndarray, commands: np.ndarray, signals: Mapping[str, np.ndarray],
              units: Mapping[str, str] = LOG_UNITS) -> Path:
    """A field log with ``name [unit]`` headers: time, the commands and ``signals`` (SI in, converted to ``units``
    where listed, SI otherwise). Returns ``path``."""
    cols: dict[str, np.ndarray] = {}
    tu = units.get("time", "s")
    cols[f"time [{tu}]"] = to_si(np.asarray(time, float), "s", tu)
    for i, c in enumerate(COMMAND_COLUMNS):
        cols[f"{c} [1]"] = np.asarray(commands, float)[:, i]
    for name, values in signals.items():
        unit = units.get(name, SIGNAL_UNITS[name])
        cols[f"{name} [{unit}]"] = to_si(np.asarray(values, float), SIGNAL_UNITS[name], unit)
    header = ",".join(cols)
    table = np.column_stack(list(cols.values()))
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, table, delimiter=",", header=header, comments="", fmt=f"%.{DIGITS}g")
    return path


def logged_channels(signals: Mapping[str, np.ndarray], cond: Condition) -> list[str]:
    """Channels a field log carries: the compared signals (a logger records sensors, not the route-2 statics or
    residuals), less the one ``cond`` drops."""
    return [s for s in COMPARED if s in signals and s != cond.missing]


def write_twin_json(path: Path, loader_dict: dict, soil_dict: dict, env_kwargs: dict) -> Path:
    """The twin as a user describes it (machine, soil, env arguments; no seed). Returns ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"scale": loader_dict, "soil": soil_dict, "env_kwargs": env_kwargs}, indent=1))
    return path
