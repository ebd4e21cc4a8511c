"""discrepancy: locate where the twin and the real machine differ, name the physics the twin left out, model it
and prove it on planted, hidden physics.

Quick use::

    from discrepancy import diagnose
    d = diagnose("real.parquet", held_out=["real_2.parquet"])   # or an EpisodeData / Recording
    d.effects, d.located, d.comparison.after

Modules (one job each): :mod:`~discrepancy.effects` (catalogue), :mod:`~discrepancy.plant` (planting effects),
:mod:`~discrepancy.twin` (replaying commands), :mod:`~discrepancy.locate` (windows, p-values, BH),
:mod:`~discrepancy.identify` (naming), :mod:`~discrepancy.fit` (parameters, intervals, before/after),
:mod:`~discrepancy.report` (JSON, Markdown; :mod:`~discrepancy.rerun_out` for rerun), :mod:`~discrepancy.bench`
(the proof). Helpers: episode (recording adapter), twin_env (the env with hooks), runner (parallel replays),
context, noise, calibrate, redundancy, sensors, search, synth, bench_cases, scoring, schema, plots, pipeline.
"""

from __future__ import annotations

from discrepancy.effects import CATALOGUE, EFFECT_NAMES, UNEXPLAINED, Effect, EffectSpec, Scales
from discrepancy.episode import EpisodeData, RecordingError, from_recording, load_episode
from discrepancy.noise import NullSpec
from discrepancy.pipeline import DiagnoseOptions, Diagnosis, ReportedEffect, diagnose
from discrepancy.twin import TwinSpec

__all__ = [
    "CATALOGUE", "EFFECT_NAMES", "UNEXPLAINED", "DiagnoseOptions", "Diagnosis", "Effect", "EffectSpec",
    "EpisodeData", "NullSpec", "RecordingError", "ReportedEffect", "Scales", "TwinSpec", "diagnose",
    "from_recording", "load_episode",
]
