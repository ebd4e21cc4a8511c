"""The one adapter between recordings and the analysis: an :class:`EpisodeData` holds commands, per-step signal
arrays, dig phases and what is known about the machine; :func:`load_episode` reads one from a file.

Files are read with :mod:`scaletwin_envs.recording` (our Parquet, or an imported CSV/Parquet with ``name [unit]``
headers; an imported log needs time and the commands, and any of the signals). Given the twin's control step, a
log sampled faster (a data logger at 50–1000 Hz, jittered timestamps) is resampled to it, short NaN gaps are
bridged and missing channels noted (:mod:`discrepancy.data.fieldlog`; what was done is in
:attr:`EpisodeData.input_report`). Everything that could make a comparison meaningless (no commands, long gaps,
out-of-range commands, time not increasing or not uniformly sampled, a log slower than the control step, too
short, no comparable signal) raises :class:`RecordingError` with a message that says what is wrong.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from discrepancy.data.channels import COMPARED, ROUTE2, RecordingError
from discrepancy.data.fieldlog import InputReport, prepare_log
from scaletwin_envs.recording import Provenance, Recording, import_recording
from scaletwin_envs.recording.schema import COMMAND_COLUMNS
from scaletwin_envs.signal_units import SIGNAL_UNITS
from scaletwin_envs.specs.loader import LoaderSpec
from scaletwin_envs.specs.soil import SoilSpec

MIN_STEPS = 10
SAMPLING_TOLERANCE = 0.05  # relative spread of the sampling step accepted as uniform


@dataclass
class EpisodeData:
    """One dig cycle: time (s), commands ``[lift, tilt, drive]`` in [-1, 1], SI signals, phases, provenance, and
    what was done to the log on input (``input_report``; None for episodes made in memory)."""

    time: np.ndarray
    commands: np.ndarray
    signals: dict[str, np.ndarray]
    phases: np.ndarray
    seed: int | None = None
    machine: LoaderSpec | None = None
    soil: SoilSpec | None = None
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    name: str = "episode"
    input_report: InputReport | None = None

    def __len__(self) -> int:
        return len(self.time)

    @property
    def dt(self) -> float:
        """Sampling step, s."""
        return float(np.median(np.diff(self.time))) if len(self.time) > 1 else float("nan")

    def matrix(self, names: tuple[str, ...]) -> np.ndarray:
        """Signals ``names`` as a (steps, len(names)) array."""
        return np.stack([self.signals[n] for n in names], axis=1)

    def head(self, steps: int) -> EpisodeData:
        """The first ``steps`` rows."""
        return EpisodeData(self.time[:steps], self.commands[:steps], {k: v[:steps] for k, v in self.signals.items()},
                           self.phases[:steps], self.seed, self.machine, self.soil, dict(self.env_kwargs), self.name,
                           self.input_report)


def from_recording(rec: Recording, name: str = "recording", control_dt: float | None = None) -> EpisodeData:
    """Adapt a :class:`~scaletwin_envs.recording.Recording`.

    Args:
        rec: the recording (SI).
        name: used in messages and reports.
        control_dt: the twin's control step, s. A log sampled faster is resampled to it (anti-aliased, see
            :mod:`discrepancy.data.fieldlog`); one sampled slower is refused. None: the log is taken at its own
            step, which must be uniform.

    Short NaN gaps in signals and commands are bridged and reported in ``input_report``, as are compared signals
    the log does not have.

    Raises:
        RecordingError: see the module docstring.
    """
    data = rec.data
    missing = [c for c in ("time", *COMMAND_COLUMNS) if c not in data.columns]
    if missing:
        raise RecordingError(f"{name}: no {missing} column(s); the twin replays the commands, so they are needed")
    time = _floats(data["time"], f"{name}: time")
    commands = np.stack([_floats(data[c], f"{name}: {c}", allow_nan=True) for c in COMMAND_COLUMNS], axis=1)
    _check_commands(commands, name)
    if len(time) < MIN_STEPS:
        raise RecordingError(f"{name}: {len(time)} rows; at least {MIN_STEPS} control steps are needed")
    _check_increasing(time, name)
    signals = {s: _floats(data[s], f"{name}: {s}", allow_nan=True) for s in (*COMPARED, *ROUTE2)
               if s in data.columns}
    phases = (data["phase"].astype(str).to_numpy() if "phase" in data.columns
              else np.full(len(time), "", dtype=object))
    log = prepare_log(time, commands, signals, np.asarray(phases, dtype=object), control_dt, name)
    _check_uniform(log.time, name)  # a log kept at its own step must be uniform; a resampled one is
    _check_commands(log.commands, name)
    if len(log.time) < MIN_STEPS:
        raise RecordingError(f"{name}: {len(log.time)} control steps after resampling; at least {MIN_STEPS} "
                             "are needed")
    prov = rec.provenance
    return EpisodeData(log.time, log.commands, log.signals, log.phases, prov.seed, _machine(prov, name),
                       _soil(prov, name), dict(prov.env_kwargs), name, log.report)


def load_episode(path: str | Path, control_dt: float | None = None) -> EpisodeData:
    """Read a recording file (our Parquet or an imported CSV/Parquet) into an :class:`EpisodeData`.

    Args:
        path: the file.
        control_dt: the twin's control step, s (see :func:`from_recording`).

    Raises:
        FileNotFoundError: no such file.
        RecordingError: the file cannot be read or is not a usable recording.
    """
    path = Path(path)
    return from_recording(read_log(path), path.name, control_dt)


def read_log(path: str | Path) -> Recording:
    """Read a recording file into an SI :class:`Recording` as it is (nothing resampled or checked yet): our
    Parquet, or a CSV/Parquet log with ``name [unit]`` headers that has time and the commands.

    Raises:
        FileNotFoundError: no such file.
        RecordingError: the file cannot be read.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no recording at {path}")
    try:
        return import_recording(path, required=("time", *COMMAND_COLUMNS))
    except (ValueError, OSError, KeyError) as exc:
        raise RecordingError(f"cannot read recording {path}: {exc}") from exc
    except Exception as exc:  # pyarrow raises its own errors on corrupted files
        raise RecordingError(f"cannot read recording {path} (corrupted?): {type(exc).__name__}: {exc}") from exc


def to_recording(ep: EpisodeData, provenance: Provenance | None = None) -> Recording:
    """An :class:`EpisodeData` as a :class:`Recording` (for writing files)."""
    cols: dict[str, Any] = {"step": np.arange(1, len(ep) + 1, dtype=np.int64), "time": ep.time}
    cols.update({c: ep.commands[:, i] for i, c in enumerate(COMMAND_COLUMNS)})
    cols.update({s: ep.signals[s] for s in SIGNAL_UNITS if s in ep.signals})
    units = {"step": "1", "time": "s", **dict.fromkeys(COMMAND_COLUMNS, "1")}
    units.update({s: SIGNAL_UNITS[s] for s in SIGNAL_UNITS if s in ep.signals})
    cols["phase"] = pd.array([str(p) for p in ep.phases], dtype="str")
    units["phase"] = "-"
    prov = provenance or Provenance(
        machine=ep.machine.to_dict() if ep.machine else None, soil=ep.soil.to_dict() if ep.soil else None,
        seed=ep.seed, control_dt=ep.dt, env_kwargs=dict(ep.env_kwargs), policy=ep.name, source="import")
    return Recording(pd.DataFrame(cols), units, prov)


def _floats(column: pd.Series, what: str, allow_nan: bool = False) -> np.ndarray:
    try:
        values = column.to_numpy(dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise RecordingError(f"{what} is not numeric ({exc})") from exc
    if allow_nan:
        if np.any(np.isinf(values)):
            raise RecordingError(f"{what} is infinite at row {int(np.flatnonzero(np.isinf(values))[0])}")
        return values
    if not np.all(np.isfinite(values)):
        bad = int(np.flatnonzero(~np.isfinite(values))[0])
        raise RecordingError(f"{what} has a missing or non-finite value at row {bad}")
    return values


def _check_commands(commands: np.ndarray, name: str) -> None:
    # per column, so that the message names the command at fault (NaN, a gap bridged later, counts as 0)
    size = np.max(np.abs(np.where(np.isfinite(commands), commands, 0.0)), axis=0, initial=0.0)
    worst = float(np.max(size, initial=0.0))
    if worst > 1.0 + 1e-6:
        column = COMMAND_COLUMNS[int(np.argmax(size))]
        raise RecordingError(f"{name}: commands must be normalised to [-1, 1] (largest |{column}| is {worst:.3g})")


def _check_increasing(time: np.ndarray, name: str) -> None:
    step = np.diff(time)
    if np.any(step <= 0):
        row = int(np.flatnonzero(step <= 0)[0]) + 1
        raise RecordingError(f"{name}: time does not increase at row {row} ({time[row - 1]} -> {time[row]} s)")


def _check_uniform(time: np.ndarray, name: str) -> None:
    step = np.diff(time)
    med = float(np.median(step))
    if np.max(np.abs(step - med)) > SAMPLING_TOLERANCE * med:
        raise RecordingError(f"{name}: time is not sampled uniformly (steps {step.min():.4g}..{step.max():.4g} s); "
                             "give the twin's control step (control_dt) to resample it")


def _machine(prov: Provenance, name: str) -> LoaderSpec | None:
    try:
        return prov.machine_spec()
    except (ValueError, TypeError) as exc:
        raise RecordingError(f"{name}: the machine in the provenance is not a valid LoaderSpec ({exc})") from exc


def _soil(prov: Provenance, name: str) -> SoilSpec | None:
    try:
        return prov.soil_spec()
    except (ValueError, TypeError) as exc:
        raise RecordingError(f"{name}: the soil in the provenance is not a valid SoilSpec ({exc})") from exc


def signal_spread(signals: Mapping[str, np.ndarray]) -> dict[str, float]:
    """A typical spread of each signal (SI): its standard deviation, floored for constant signals."""
    out = {}
    for k, v in signals.items():
        sd = float(np.std(v))
        out[k] = sd if sd > 0 else max(abs(float(np.mean(v))), 1e-12)
    return out
