"""The run directory written by :class:`scaling.runs.pipeline.ScalingPipeline` and read back by the CLI.

Layout (JSON + safetensors + CSV + rerun files; no pickle)::

    RUN/
      metrics.json          held-out metrics per model, held-out machines, miniature, domain, groups
      provenance.json       code version, pipeline config, seed, data hashes, versions, machine
      reference.json        the source row (ER12; the paper's "model" row): every signal, SI
      mini.json             the miniature validation (``{"loads_kg": [...], "models": {...}}``)
      groups/<eq>.json      the chosen group set (a scaling.dimensions.pi_theorem manifest), groups/<eq>_ranking.csv
      models/<name>/        config.json + weights.safetensors (:meth:`DeltaModel.save`), metrics.json,
                            provenance.json, fit.rrd (rerun log of the fit)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from scaling.dimensions.pi_theorem import write_manifest
from scaling.models import DeltaModel, load_model
from scaling.runs.pipeline import PipelineResult
from scaling.runs.provenance import provenance, read_json, write_json

METRICS, PROVENANCE, REFERENCE, MINI = "metrics.json", "provenance.json", "reference.json", "mini.json"


def save_run(result: PipelineResult, out_dir: str | Path, rerun: bool = True) -> Path:
    """Write ``result`` as a run directory (see module docstring); returns its path."""
    out = Path(out_dir)
    for sub in ("models", "groups"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    cfg = result.config
    prov = provenance("run", cfg.to_dict(), cfg.seed, result.data_hashes, reference_index=_plain(result.reference.name))
    write_json(out / PROVENANCE, prov)
    write_json(out / REFERENCE, {"index": _plain(result.reference.name),
                                 "row": {k: _plain(v) for k, v in result.reference.items()}})
    groups = {}
    for name, choice in result.choices.items():
        write_manifest([choice.pi_set], out / "groups" / f"{name}.json")
        choice.ranking.to_csv(out / "groups" / f"{name}_ranking.csv", index=False)
        groups[name] = {"output": choice.output.expression(), "inputs": [g.expression() for g in choice.inputs],
                        "n_admissible": len(choice.ranking), "n_candidates": choice.n_candidates,
                        "score": float(choice.ranking.iloc[0]["score"]), "z": float(choice.ranking.iloc[0]["z"])}
    for name, model in result.models.items():
        mdir = model.save(out / "models" / name)
        spec = next(s for s in cfg.models if s.name == name)
        write_json(mdir / METRICS, {"held_out_episodes": result.metrics[name],
                                    "held_out_machines": result.held_out.get(name, {}),
                                    "mini": {"mean_abs_pct_error": result.mini.mean_abs(name),
                                             "pct_error": result.mini.pct_error(name)}})
        write_json(mdir / PROVENANCE, provenance("model", {"spec": {"name": spec.name, "cls": spec.cls,
                                                                     "groups": spec.groups},
                                                            "config": model.get_config()},
                                                 cfg.seed, result.data_hashes, run=str(out)))
        if rerun:
            from scaling.runs.rerun_log import log_fit

            test = result.test_sets[spec.groups]
            log_fit(model, mdir / "fit.rrd", name=name, actual=test.delta, predicted=model.predict(test),
                    metrics=result.metrics[name])
    write_json(out / MINI, result.mini.to_json())
    mini_extra = {n: result.mini.coverage(n) for n in result.mini.intervals}
    write_json(out / METRICS, {"models": result.metrics, "held_out_machines": result.held_out,
                               "mini": {**result.mini.to_json(), "interval_coverage": mini_extra},
                               "domain": result.domain, "groups": groups,
                               "reference_index": _plain(result.reference.name), "data_hashes": result.data_hashes})
    return out


def load_run(run_dir: str | Path) -> tuple[dict[str, DeltaModel], pd.Series]:
    """(models by name, reference row) of a run directory.

    Raises:
        FileNotFoundError: ``run_dir`` is not a run directory.
    """
    path = Path(run_dir)
    if not (path / REFERENCE).exists() or not (path / "models").is_dir():
        raise FileNotFoundError(f"{path} is not a scaletwin fit directory (no {REFERENCE} or models/)")
    ref = read_json(path / REFERENCE)
    reference = pd.Series(ref["row"], name=ref["index"])
    models = {d.name: load_model(d) for d in sorted((path / "models").iterdir()) if (d / "config.json").exists()}
    order = ["ffnn", "ffnn-pose", "gru-eq10", "gru-eq23", "power-law", "deep-ensemble", "direct-pi"]
    return dict(sorted(models.items(), key=lambda kv: order.index(kv[0]) if kv[0] in order else len(order))), reference


def read_metrics(run_dir: str | Path) -> dict[str, Any]:
    return read_json(Path(run_dir) / METRICS)


def _plain(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    return value
