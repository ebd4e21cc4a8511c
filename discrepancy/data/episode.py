"""The one adapter between recordings and the analysis: an :class:`EpisodeData` holds commands, per-step signal
arrays, dig phases and what is known about the machine; :func:`load_episode` reads one from a file.

Files are read with :mod:`scaletwin_envs.recording` (our Parquet, or an imported CSV/Parquet with ``name [unit]``
headers). Everything that could make a comparison meaningless (no commands, NaN or out-of-range commands, time
not increasing or not uniformly sampled, too short, no comparable signal) raises :class:`RecordingError` with a
message that says what is wrong.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from scaletwin_envs.recording import Provenance, Recording, import_recording
from scaletwin_envs.recording.schema import COMMAND_COLUMNS
from scaletwin_envs.signal_units import SIGNAL_UNITS
from scaletwin_envs.specs.loader import LoaderSpec
from scaletwin_envs.specs.soil import SoilSpec

#: Signals compared between real and twin (route-2 and residual columns are the linkage-redundancy check's).
COMPARED = tuple(s for s in SIGNAL_UNITS if not s.endswith("_route2") and not s.startswith("residual_"))
ROUTE2 = tuple(s for s in SIGNAL_UNITS if s.endswith("_route2"))
MIN_STEPS = 10
SAMPLING_TOLERANCE = 0.05  # relative spread of the sampling step accepted as uniform


class RecordingError(ValueError):
    """A recording that cannot be compared with the twin (corrupted, incomplete or mismatched)."""


@dataclass
class EpisodeData:
    """One dig cycle: time (s), commands ``[lift, tilt, drive]`` in [-1, 1], SI signals, phases, provenance."""

    time: np.ndarray
    commands: np.ndarray
    signals: dict[str, np.ndarray]
    phases: np.ndarray
    seed: int | None = None
    machine: LoaderSpec | None = None
    soil: SoilSpec | None = None
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    name: str = "episode"

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
                           self.phases[:steps], self.seed, self.machine, self.soil, dict(self.env_kwargs), self.name)


def from_recording(rec: Recording, name: str = "recording") -> EpisodeData:
    """Adapt a :class:`~scaletwin_envs.recording.Recording`.

    Raises:
        RecordingError: see the module docstring.
    """
    data = rec.data
    missing = [c for c in ("time", *COMMAND_COLUMNS) if c not in data.columns]
    if missing:
        raise RecordingError(f"{name}: no {missing} column(s); the twin replays the commands, so they are needed")
    time = _floats(data["time"], f"{name}: time")
    commands = np.stack([_floats(data[c], f"{name}: {c}") for c in COMMAND_COLUMNS], axis=1)
    _check_commands(commands, name)
    _check_time(time, name)
    signals = {s: data[s].to_numpy(dtype=np.float64) for s in (*COMPARED, *ROUTE2) if s in data.columns}
    usable = [s for s in COMPARED if s in signals and np.all(np.isfinite(signals[s]))]
    if not usable:
        raise RecordingError(f"{name}: none of the compared signals {list(COMPARED)} is present and finite")
    signals = {k: v for k, v in signals.items() if np.all(np.isfinite(v))}
    phases = (data["phase"].astype(str).to_numpy() if "phase" in data.columns
              else np.full(len(time), "", dtype=object))
    prov = rec.provenance
    return EpisodeData(time, commands, signals, np.asarray(phases, dtype=object), prov.seed, _machine(prov, name),
                       _soil(prov, name), dict(prov.env_kwargs), name)


def load_episode(path: str | Path) -> EpisodeData:
    """Read a recording file (our Parquet or an imported CSV/Parquet) into an :class:`EpisodeData`.

    Raises:
        FileNotFoundError: no such file.
        RecordingError: the file cannot be read or is not a usable recording.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no recording at {path}")
    try:
        rec = import_recording(path)
    except (ValueError, OSError, KeyError) as exc:
        raise RecordingError(f"cannot read recording {path}: {exc}") from exc
    except Exception as exc:  # pyarrow raises its own errors on corrupted files
        raise RecordingError(f"cannot read recording {path} (corrupted?): {type(exc).__name__}: {exc}") from exc
    return from_recording(rec, path.name)


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


def _floats(column: pd.Series, what: str) -> np.ndarray:
    try:
        values = column.to_numpy(dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise RecordingError(f"{what} is not numeric ({exc})") from exc
    if not np.all(np.isfinite(values)):
        bad = int(np.flatnonzero(~np.isfinite(values))[0])
        raise RecordingError(f"{what} has a missing or non-finite value at row {bad}")
    return values


def _check_commands(commands: np.ndarray, name: str) -> None:
    worst = float(np.max(np.abs(commands))) if commands.size else 0.0
    if worst > 1.0 + 1e-6:
        raise RecordingError(f"{name}: commands must be normalised to [-1, 1] (largest |command| is {worst:.3g})")


def _check_time(time: np.ndarray, name: str) -> None:
    if len(time) < MIN_STEPS:
        raise RecordingError(f"{name}: {len(time)} rows; at least {MIN_STEPS} control steps are needed")
    step = np.diff(time)
    if np.any(step <= 0):
        row = int(np.flatnonzero(step <= 0)[0]) + 1
        raise RecordingError(f"{name}: time does not increase at row {row} ({time[row - 1]} -> {time[row]} s)")
    med = float(np.median(step))
    if np.max(np.abs(step - med)) > SAMPLING_TOLERANCE * med:
        raise RecordingError(f"{name}: time is not sampled uniformly (steps {step.min():.4g}..{step.max():.4g} s); "
                             "resample to the control step first")


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
