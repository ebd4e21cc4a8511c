"""discrepancy: locate where the twin and the real machine differ, name the physics the twin left out, model it
and prove it on planted, hidden physics.

Quick use::

    from discrepancy import diagnose
    d = diagnose("real.parquet", held_out=["real_2.parquet"])   # or an EpisodeData / Recording
    d.effects, d.located, d.comparison.after

Layout (stages in pipeline order; data flows one way, each stage a sub-package):
:mod:`~discrepancy.data` (recordings and field logs in), :mod:`~discrepancy.twin` (spec, hooked env, planting,
replays), :mod:`~discrepancy.stats` (noise model, null, localisation, redundancy), :mod:`~discrepancy.search`
(screening, naming, fit, budget), :mod:`~discrepancy.report` (JSON, Markdown, rerun). Shared by all:
:mod:`~discrepancy.effects` (the catalogue) and :mod:`~discrepancy.context` (one episode against its twin);
:mod:`~discrepancy.pipeline` runs the stages. :mod:`~discrepancy.bench` is the proof, apart from the tool.
"""

from __future__ import annotations

from discrepancy.data.channels import RecordingError
from discrepancy.data.episode import EpisodeData, from_recording, load_episode
from discrepancy.effects import CATALOGUE, EFFECT_NAMES, UNEXPLAINED, Effect, EffectSpec, Scales
from discrepancy.pipeline import DiagnoseOptions, Diagnosis, ReportedEffect, diagnose
from discrepancy.search.identify import IdentifyOptions
from discrepancy.stats.noise import NullSpec
from discrepancy.twin.spec import TwinSpec

__all__ = [
    "CATALOGUE", "EFFECT_NAMES", "UNEXPLAINED", "DiagnoseOptions", "Diagnosis", "Effect", "EffectSpec",
    "EpisodeData", "IdentifyOptions", "NullSpec", "RecordingError", "ReportedEffect", "Scales", "TwinSpec", "diagnose",
    "from_recording", "load_episode",
]
