"""Recordings of dig episodes: Parquet datasets with units and provenance, imports, sweeps and rerun logs.

* :func:`record_episode` / :class:`EpisodeRecorder`: record any loader env instance into a :class:`Recording`.
* :meth:`Recording.to_parquet` / :func:`read_recording`: lossless Parquet round trip (units, provenance).
* :func:`replay`: step the stored commands in the twin rebuilt from the provenance.
* :func:`import_recording`: a real machine's CSV/Parquet log with ``name [unit]`` headers, converted to SI.
* :class:`SweepSpec` / :func:`run_sweep` / :func:`load_dataset`: resumable, parallel dataset sweeps.
* :mod:`~scaletwin_envs.recording.rerun_log`: :class:`RerunLogger` (live) and :func:`log_episode_rrd` (files);
  imported lazily, so that recording does not load rerun.
"""

from __future__ import annotations

import importlib
from typing import Any

from scaletwin_envs.recording.importer import import_recording
from scaletwin_envs.recording.recording import Provenance, Recording, read_recording
from scaletwin_envs.recording.replay import make_twin, replay
from scaletwin_envs.recording.schema import SCHEMA_VERSION

#: Names whose modules load MuJoCo (recorder, sweep) or rerun (rerun_log): imported on first use, so that reading
#: recordings (serving, importers) loads neither. (``replay`` is eager: the function shares its module's name.)
_LAZY: dict[str, str] = {
    "EpisodeRecorder": "recorder", "record_episode": "recorder",
    "EpisodeTask": "sweep", "SweepSpec": "sweep", "load_dataset": "sweep", "run_sweep": "sweep",
    "RerunLogger": "rerun_log", "log_episode_rrd": "rerun_log", "open_stream": "rerun_log",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "SCHEMA_VERSION", "EpisodeRecorder", "EpisodeTask", "Provenance", "Recording", "RerunLogger", "SweepSpec",
    "import_recording", "load_dataset", "log_episode_rrd", "make_twin", "open_stream", "read_recording",
    "record_episode", "replay", "run_sweep",
]
