"""scaling: Buckingham-Pi groups, group-set selection and distortion-aware scaling of digital twins.

δ1 convention (everywhere): source = the calibrated machine (the paper's "model", e.g. one ER12 twin row), target =
the machine to predict (the paper's "prototype"); δ1 = π1(source)/π1(target) and, for π1 = F21/F31,
F21_target = F31_target · π1(source) / δ1 (Eq. 22). See :mod:`scaling.factors`.

Light names (dimensional analysis, selection, factors) are imported eagerly; the model, data, pipeline and
validation names (torch, MuJoCo) load on first use.
"""

from __future__ import annotations

import importlib
from typing import Any

from scaling.delta_dataset import DeltaDataset
from scaling.factors import LogDistortion, distortions, prediction_factor, recover_target
from scaling.groups import PiGroup
from scaling.pi_theorem import PiSet, enumerate_pi_sets, pi_groups, read_manifest, write_manifest
from scaling.scorers import CrossValidatedR2, MutualInformation, PearsonRMS, Scorer, SpearmanRMS
from scaling.selection import rank_pi_sets, select_pi_set

_LAZY: dict[str, str] = {
    # models
    "FFNN": "scaling.models", "GRUModel": "scaling.models", "DeepEnsemble": "scaling.models",
    "DirectPi": "scaling.models", "PowerLaw": "scaling.models", "DeltaModel": "scaling.models",
    "load_model": "scaling.models",
    # group choice, data, pipeline, validation, grid search (the paper run: scaling.reproduce.reproduce)
    "EQ10": "scaling.group_choice", "EQ23": "scaling.group_choice", "choose_groups": "scaling.group_choice",
    "DatasetSpec": "scaling.data", "DataBundle": "scaling.data", "STANDARD": "scaling.data",
    "HELD_OUT": "scaling.data", "generate_frame": "scaling.data", "generate_recordings": "scaling.data",
    "load_recordings": "scaling.data", "StaticHoldPolicy": "scaling.holds",
    "ModelSpec": "scaling.pipeline", "PipelineConfig": "scaling.pipeline", "PipelineResult": "scaling.pipeline",
    "ScalingPipeline": "scaling.pipeline", "load_run": "scaling.run_io",
    "MiniValidation": "scaling.validation", "static_rows": "scaling.validation", "validate_mini": "scaling.validation",
    "env_at_rest": "scaling.validation", "GridSearch": "scaling.grid",
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
