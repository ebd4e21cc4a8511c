"""The ``"scaling-model"`` kind: a fitted δ1 model as ``config.json`` + ``weights.safetensors`` and a JSON card.

:func:`save_scaling_model` writes a checkpoint (the model's own persistence, :meth:`DeltaModel.save`, then the card
with every file's sha256) and checks that the rebuilt :class:`~zoo.serving.ScalingModel` reproduces the fitted
model's δ1 on the checkpoint's check rows. :func:`build_scaling_model` is the kind's builder, called by
:func:`zoo.load` only after every hash was verified; it reads JSON and safetensors only.

Card fields (besides the common ones, :mod:`zoo.checkpoint`):

``predicts``          the scaled variable, its unit and Eq. (22)
``delta_convention``  δ1 = π1(source)/π1(target), source = calibrated machine (paper: model)
``groups``            the group set (``eq10``/``eq23``): π1 and the input groups with their exponents
``source``            the calibrated reference row the model was trained against (SI), the default source
``inputs``            target quantities with their SI units
``interval``          method (``residual-quantiles``, ``ensemble`` or ``learned-scale``), coverage, quantiles of ln δ1
                      residuals; ``learned-scale`` adds the per-row interval
                      (:class:`scaling.evaluation.conformal.RowInterval`); ``multi_source`` (product-line cards) the
                      interval and risk calibrated for several sources
                      (:meth:`zoo.serving.ScalingModel.scale_force_sources`)
``training_range``    per input group, min/max of the distortion feature g on the training pairs
``training``          machines, soils, dataset spec and hashes, pipeline config, seed, code version, fit time
``metrics``           held-out episodes (R² of δ1), held-out machines, miniature errors, the check set; product-line
                      cards also ``multi_source``: the held-out machines judged from several sources
``risk``              (optional) the risk served per row (:class:`scaling.evaluation.conformal.RowRisk`: P(F21
                      more than 10 % off), read off the interval), its novelty rows in ``risk.safetensors``
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from safetensors.numpy import load_file, save_file

from scaling.data.delta_dataset import DeltaDataset
from scaling.evaluation.conformal import RowInterval, RowRisk
from scaling.models import DeltaModel, load_model
from scaling.models.base import CONFIG_FILE, WEIGHTS_FILE
from scaling.runs.provenance import to_jsonable
from zoo.checkpoint import CARD_NAME, finish_checkpoint, prepare_directory
from zoo.errors import CheckpointError
from zoo.loading import load, register_builder
from zoo.serving.inputs import header, read_table, split_header
from zoo.serving.model import ExtrapolationWarning, ScalingModel

KIND = "scaling-model"
CHECK_FILE = "check.csv"
RISK_FILE = "risk.safetensors"
CARD_KEYS = ("predicts", "delta_convention", "groups", "source", "inputs", "interval", "training_range", "training",
             "metrics")


def save_scaling_model(model: DeltaModel, directory: str | Path, card_fields: Mapping[str, Any],
                       check_rows: pd.DataFrame | None = None, overwrite: bool = False,
                       risk: RowRisk | None = None) -> Path:
    """Write a scaling-model checkpoint; returns its directory.

    Args:
        model: a fitted FFNN, GRUModel or DeepEnsemble.
        card_fields: the card's content (:data:`CARD_KEYS` at least; see the module docstring).
        check_rows: a small held-out table (SI; ``episode``, ``t`` and the signals) stored as ``check.csv`` with
            ``name [unit]`` headers, on which the card's ``metrics.check_set`` was measured.
        risk: the risk the served model computes per row (:class:`~scaling.evaluation.conformal.RowRisk`): its
            parameters go on the card (``risk``), its novelty rows into ``risk.safetensors``.
    """
    missing = [k for k in CARD_KEYS if k not in card_fields]
    if missing:
        raise ValueError(f"card fields missing {missing}")
    directory = prepare_directory(directory, [CONFIG_FILE, WEIGHTS_FILE, CARD_NAME, CHECK_FILE, RISK_FILE],
                                  overwrite)
    model.save(directory)
    (directory / WEIGHTS_FILE).chmod(0o644)
    files = [CONFIG_FILE, WEIGHTS_FILE]
    fields = dict(card_fields)
    if risk is not None:
        params, rows = risk.state()
        save_file({"novelty_rows": np.ascontiguousarray(rows, dtype=np.float64)}, str(directory / RISK_FILE))
        (directory / RISK_FILE).chmod(0o644)
        fields["risk"] = to_jsonable({**params, "file": RISK_FILE})
        files.append(RISK_FILE)
    else:
        (directory / RISK_FILE).unlink(missing_ok=True)
    if check_rows is not None:
        check_rows.rename(columns=_check_header).to_csv(directory / CHECK_FILE, index=False, float_format="%.17g")
        files.append(CHECK_FILE)
    else:  # a check set left by an earlier save would be unlisted: loading refuses unlisted files
        (directory / CHECK_FILE).unlink(missing_ok=True)
    finish_checkpoint(directory, KIND, {"model": {"class": model.name, "config": model.get_config()}, **fields},
                      files)
    _check_round_trip(model, directory)
    return directory


def build_scaling_model(directory: Path, card: dict[str, Any], ref: str) -> ScalingModel:
    """Builder of the ``"scaling-model"`` kind (called by :func:`zoo.load` after the hashes were verified)."""
    missing = [k for k in CARD_KEYS if k not in card]
    if missing or CONFIG_FILE not in card["files"] or WEIGHTS_FILE not in card["files"]:
        raise CheckpointError(f"{directory}: malformed scaling-model card, missing "
                              f"{missing or [f for f in (CONFIG_FILE, WEIGHTS_FILE) if f not in card['files']]}")
    try:
        model = load_model(directory)
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise CheckpointError(f"{directory}: model files do not rebuild a δ1 model ({type(exc).__name__}: {exc})"
                              ) from exc
    if model.groups_ != {k: card["groups"].get(k) for k in ("output", "inputs", "target_variable")}:
        raise CheckpointError(f"{directory}: the model's groups differ from the card's")
    try:
        return ScalingModel(model, card, ref, _load_risk(directory, card))
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{directory}: malformed scaling-model card ({type(exc).__name__}: {exc})") from exc


register_builder(KIND, build_scaling_model)


def _load_risk(directory: Path, card: Mapping[str, Any]) -> RowRisk | None:
    """The card's risk (its novelty rows from the hashed ``risk.safetensors``), or None."""
    if "risk" not in card:
        return None
    name = card["risk"].get("file")
    if name not in card["files"]:
        raise CheckpointError(f"{directory}: the card's risk names {name!r}, which is not a listed file")
    learned = card.get("interval", {}).get("learned_scale")
    return RowRisk.from_state(card["risk"], load_file(str(directory / name))["novelty_rows"],
                              None if learned is None else RowInterval.from_state(learned))


def _check_header(column: str) -> str:
    return {"machine": "machine", "episode": "episode", "t": "t [s]"}.get(column) or header(column)


def check_rows(directory: str | Path) -> pd.DataFrame:
    """The checkpoint's ``check.csv`` (``name [unit]`` headers, SI)."""
    return read_table(Path(directory) / CHECK_FILE)


def _check_round_trip(model: DeltaModel, directory: Path) -> None:
    """The served model reproduces the fitted one's δ1 on the check rows (float32 nets: to 1e-5 relative)."""
    served = load(directory)
    if not (directory / CHECK_FILE).exists():
        return
    rows = check_rows(directory)
    ours = reference_prediction(model, served, rows)
    with warnings.catch_warnings():  # a numerical round trip: whether the rows extrapolate is beside the point
        warnings.simplefilter("ignore", ExtrapolationWarning)
        theirs = served.scale_force(None, rows).delta1
    if not np.allclose(ours, theirs, rtol=1e-5, atol=0):
        raise CheckpointError(f"{directory}: the served model does not reproduce the fitted model's δ1 "
                              f"(max rel. diff {np.max(np.abs(theirs / ours - 1)):.2e})")


def reference_prediction(model: DeltaModel, served: ScalingModel, rows: pd.DataFrame) -> np.ndarray:
    """δ1 of ``rows`` predicted through the scaling package (DeltaDataset + model.predict), in the row order."""
    si = rows.rename(columns=lambda c: split_header(c)[0])
    pairs = DeltaDataset.from_pairs(served.reference, si, served.output_group, served.input_groups, warn=False)
    if len(pairs) != len(si):
        raise CheckpointError("check rows contain rows the scaling package drops (non-finite groups)")
    return model.predict(pairs)
