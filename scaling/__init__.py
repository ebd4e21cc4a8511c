"""scaling: Buckingham-Pi groups, group-set selection and distortion-aware scaling of digital twins.

δ1 convention (everywhere): source = the calibrated machine (the paper's "model", e.g. one ER12 twin row), target =
the machine to predict (the paper's "prototype"); δ1 = π1(source)/π1(target) and, for π1 = F21/F31,
F21_target = F31_target · π1(source) / δ1 (Eq. 22). See :mod:`scaling.dimensions.factors`.

The package is laid out as its pipeline, one sub-package per stage; data flows down the list, and no stage
imports one below it:

* :mod:`scaling.dimensions`: units, Π groups, exact Buckingham-Pi sets, group-set scoring and selection, the
  distortion and prediction factors (Eq. 17–22);
* :mod:`scaling.data`: recordings of simulated machines (dig cycles, static holds), the product line's matched
  rows and the δ1 pair data sets;
* :mod:`scaling.models`: the δ1 models (registry, pickle-free storage), what serving reads off a fitted model,
  grid search;
* :mod:`scaling.evaluation`: metrics and row filters, the miniature validation, the leave-machine-out proof and
  intervals and error scores calibrated on held-out machines;
* :mod:`scaling.runs`: the paper's pipeline and reproduction, reports, plots, rerun logs, saved runs, provenance.

Light names (dimensional analysis, selection, factors) are imported eagerly; the model, data, pipeline and
validation names (torch, MuJoCo) load on first use.
"""

from __future__ import annotations

import importlib
from typing import Any

from scaling.data.delta_dataset import DeltaDataset
from scaling.dimensions.factors import LogDistortion, distortions, prediction_factor, recover_target
from scaling.dimensions.groups import PiGroup
from scaling.dimensions.pi_theorem import PiSet, enumerate_pi_sets, pi_groups, read_manifest, write_manifest
from scaling.dimensions.scorers import CrossValidatedR2, MutualInformation, PearsonRMS, Scorer, SpearmanRMS
from scaling.dimensions.selection import rank_pi_sets, select_pi_set

_GROUP_CHOICE, _RECORDINGS, _PIPELINE, _MINIATURE = ("scaling.dimensions.group_choice", "scaling.data.recordings",
                                                    "scaling.runs.pipeline", "scaling.evaluation.miniature")
_LAZY: dict[str, str] = {
    # models
    "FFNN": "scaling.models", "GRUModel": "scaling.models", "DeepEnsemble": "scaling.models",
    "DirectPi": "scaling.models", "PowerLaw": "scaling.models", "DeltaModel": "scaling.models",
    "load_model": "scaling.models", "GridSearch": "scaling.models.grid",
    # group choice, data, pipeline, validation (the paper run: scaling.runs.reproduce.reproduce)
    "EQ10": _GROUP_CHOICE, "EQ23": _GROUP_CHOICE, "choose_groups": _GROUP_CHOICE,
    "DatasetSpec": _RECORDINGS, "DataBundle": _RECORDINGS, "STANDARD": _RECORDINGS, "HELD_OUT": _RECORDINGS,
    "generate_frame": _RECORDINGS, "generate_recordings": _RECORDINGS, "load_recordings": _RECORDINGS,
    "StaticHoldPolicy": "scaling.data.holds",
    "ModelSpec": _PIPELINE, "PipelineConfig": _PIPELINE, "PipelineResult": _PIPELINE, "ScalingPipeline": _PIPELINE,
    "load_run": "scaling.runs.run_io",
    "MiniValidation": _MINIATURE, "static_rows": _MINIATURE, "validate_mini": _MINIATURE, "env_at_rest": _MINIATURE,
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "CrossValidatedR2",
    "DeltaDataset",
    "LogDistortion",
    "MutualInformation",
    "PearsonRMS",
    "PiGroup",
    "PiSet",
    "Scorer",
    "SpearmanRMS",
    "distortions",
    "enumerate_pi_sets",
    "pi_groups",
    "prediction_factor",
    "rank_pi_sets",
    "read_manifest",
    "recover_target",
    "select_pi_set",
    "write_manifest",
    *sorted(_LAZY),
]
