"""The training pipeline: recordings → group sets → δ1 data set → fits → metrics → a run directory.

δ1 convention (:mod:`scaling.dimensions.factors`): source = one reference row of the calibrated ER12 twin (the paper's
"model"), target = every other row / machine (the paper's "prototype"); δ1 = π1(source)/π1(target) with
π1 = F21/F31 (Eq. 13, 20); F21_target = F31_target · π1(source) / δ1 (Eq. 22).

Steps of :meth:`ScalingPipeline.run`:

1. keep the rows inside the scaling domain (:func:`scaling.evaluation.metrics.in_domain`);
2. choose the Eq. (10) and Eq. (23) group sets (:func:`scaling.dimensions.group_choice.choose_groups`: candidates
   from the Buckingham-Pi enumeration, π1 = F21/F31, finite at rest, ranked by the paper's RMS-Pearson filter);
3. pick the reference row (:func:`scaling.evaluation.metrics.pick_reference`) and build the δ1 pairs;
4. hold out whole episodes (:func:`scaling.evaluation.metrics.split_episodes`, the same for every model);
5. fit every :class:`ModelSpec` and score it on the held-out episodes;
6. score machines never trained on (``held_out`` data) and the miniature validation
   (:mod:`scaling.evaluation.miniature`).

It returns a :class:`PipelineResult`; :func:`scaling.runs.run_io.save_run` writes it as a run directory (with a
rerun log of each fit), the next stage, which reads the result and never the pipeline.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from scaling.data.delta_dataset import DeltaDataset
from scaling.data.recordings import DataBundle
from scaling.dimensions.group_choice import GroupChoice, choose_groups
from scaling.evaluation import metrics as ev
from scaling.evaluation.miniature import MiniValidation, validate_mini
from scaling.models import DeltaModel, model_class
from scaling.models.fitted import model_groups


@dataclass(frozen=True)
class ModelSpec:
    """One model of a run: ``name`` (directory and table name), registered ``cls``, group set ``groups``
    (``"eq10"`` or ``"eq23"``, optionally ``+pose``) and constructor keyword arguments ``config``."""

    name: str
    cls: str
    groups: str = "eq10"
    config: Mapping[str, Any] = field(default_factory=dict)

    def build(self, **overrides: Any) -> DeltaModel:
        return model_class(self.cls)(**{**self.config, **overrides})


FFNN_CONFIG: dict[str, Any] = {"hidden_layers": 3, "units": 64, "dropout": 0.0, "lr": 3e-3, "epochs": 800,
                               "batch_size": 256, "patience": 80}
GRU_CONFIG: dict[str, Any] = {"hidden_size": 48, "num_layers": 1, "window": 64, "stride": 16, "burn_in": 8,
                              "lr": 5e-3, "epochs": 150, "batch_size": 32, "patience": 25}
ENSEMBLE_CONFIG: dict[str, Any] = {"k": 5, "hidden_layers": 3, "units": 64, "lr": 3e-3, "epochs": 400,
                                   "batch_size": 512, "patience": 40}

#: The paper's three models, its baseline, a power law, an ensemble for intervals, and our FFNN that also sees the
#: linkage pose (:data:`scaling.dimensions.group_choice.POSE_GROUPS`).
DEFAULT_MODELS: tuple[ModelSpec, ...] = (
    ModelSpec("ffnn", "FFNN", "eq10", FFNN_CONFIG),
    ModelSpec("ffnn-pose", "FFNN", "eq10+pose", FFNN_CONFIG),
    ModelSpec("gru-eq10", "GRUModel", "eq10", GRU_CONFIG),
    ModelSpec("gru-eq23", "GRUModel", "eq23", GRU_CONFIG),
    ModelSpec("power-law", "PowerLaw", "eq10"),
    ModelSpec("direct-pi", "DirectPi", "eq10"),
    ModelSpec("deep-ensemble", "DeepEnsemble", "eq10", ENSEMBLE_CONFIG),
)


def model_specs(names: Sequence[str] | None = None,
                specs: Sequence[ModelSpec] = DEFAULT_MODELS) -> tuple[ModelSpec, ...]:
    """The specs named in ``names`` (all of ``specs`` if None), in the order of ``specs``."""
    if names is None:
        return tuple(specs)
    known = {s.name: s for s in specs}
    unknown = sorted(set(names) - set(known))
    if unknown:
        raise ValueError(f"unknown models {unknown}; choose from {sorted(known)}")
    return tuple(s for s in specs if s.name in set(names))


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of a run (all recorded in its provenance).

    Attributes:
        models: what to fit.  source_machine: the calibrated twin (paper: model).
        reference: ``"static"`` or ``"random"`` (:func:`~scaling.evaluation.metrics.pick_reference`).
        min_pi1, settle_steps: scaling domain (:func:`~scaling.evaluation.metrics.in_domain`,
            :func:`~scaling.evaluation.metrics.after_settling`).  test_fraction: held-out episodes.
        seed: seeds the split, the scorer's shuffles, every model and (unless ``reference_seed``) the reference draw.
        reference_seed: seed of the reference draw alone (None: ``seed``).
        scorer, n_shuffles: group-set ranking.  rel_eps: ε_n/median|π_n| of the log-distortion features.
        coverage: interval level of ensembles.  threads: torch threads per fit.
    """

    models: tuple[ModelSpec, ...] = DEFAULT_MODELS
    source_machine: str = "er12"
    reference: str = "static"
    min_pi1: float = 0.1
    settle_steps: int = 10
    test_fraction: float = 0.2
    seed: int = 0
    reference_seed: int | None = None
    scorer: str = "pearson"
    n_shuffles: int = 10
    rel_eps: float = 0.1
    coverage: float = 0.9
    threads: int | None = 1

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class PipelineResult:
    """Everything a run produced (the run directory holds the same, on disk)."""

    config: PipelineConfig
    choices: dict[str, GroupChoice]
    reference: pd.Series
    models: dict[str, DeltaModel]
    metrics: dict[str, dict[str, Any]]
    held_out: dict[str, dict[str, dict[str, Any]]]
    mini: MiniValidation
    test_sets: dict[str, DeltaDataset]
    test_kinds: dict[str, np.ndarray]
    domain: dict[str, int]
    data_hashes: dict[str, str]

    def headline(self) -> dict[str, Any]:
        """The numbers the issue's targets are about."""
        out: dict[str, Any] = {name: {"r2_dig": m.get("r2_dig"), "r2": m.get("r2")} for name, m in self.metrics.items()}
        out["mini"] = {n: self.mini.mean_abs(n) for n in self.mini.predicted}
        return out


@dataclass
class Prepared:
    """What every model of a run shares: the in-domain training table, the group sets, the reference row and the
    δ1 (train, test) pairs per group set (``sets[name]``), split by the same held-out episodes."""

    frame: pd.DataFrame
    domain: dict[str, int]
    choices: dict[str, GroupChoice]
    reference: pd.Series
    sets: dict[str, tuple[DeltaDataset, DeltaDataset]]


class ScalingPipeline:
    """Strategy object for one run; :meth:`run` is deterministic given the data and the config's seed."""

    def __init__(self, config: PipelineConfig | None = None) -> None:
        self.config = config or PipelineConfig()

    def prepare(self, train: pd.DataFrame) -> Prepared:
        """Steps 1–4: domain, group sets, reference row, episode split and the δ1 (train, test) pairs per set."""
        cfg = self.config
        frame, domain = self._domain(train)
        choices = {g: choose_groups(frame, g, cfg.scorer, cfg.n_shuffles, cfg.seed)
                   for g in sorted({m.groups for m in cfg.models})}
        ref_seed = cfg.seed if cfg.reference_seed is None else cfg.reference_seed
        ref_index = ev.pick_reference(frame, cfg.source_machine, cfg.reference, ref_seed, cfg.min_pi1)
        test_keys = ev.split_episodes(frame, cfg.test_fraction, cfg.seed)
        sets = {g: self._split(frame, c, ref_index, test_keys) for g, c in choices.items()}
        return Prepared(frame, domain, choices, frame.loc[ref_index], sets)

    def run(self, data: DataBundle, *, progress: bool = True, prepared: Prepared | None = None) -> PipelineResult:
        """Fit and evaluate every model on ``data.train``; score ``data.held_out`` machines if given (writes
        nothing: :func:`scaling.runs.run_io.save_run` does).

        Args:
            data: training recordings (and optionally machines never trained on).
            progress: progress bars.
            prepared: the output of :meth:`prepare` on ``data.train`` (computed if None).
        """
        cfg = self.config
        prep = prepared or self.prepare(data.train)
        held = None if data.held_out is None else self._domain(data.held_out)[0]
        models, metrics, held_out = {}, {}, {}
        bar = tqdm(cfg.models, desc="fit", unit="model", disable=not progress)
        for spec in bar:
            bar.set_postfix(model=spec.name)
            train, test = prep.sets[spec.groups]
            model = spec.build(**self._overrides(spec))
            start = time.perf_counter()
            model.fit(train)
            fit_s = time.perf_counter() - start
            models[spec.name] = model
            metrics[spec.name] = {**ev.delta_metrics(model, test, ev.kinds_of(test, prep.frame)), "fit_s": fit_s,
                                  "n_train": len(train), "groups": spec.groups, "class": spec.cls}
            if held is not None:
                held_out[spec.name] = self._held_out(model, prep.reference, held)
        bar.close()
        mini = validate_mini(models, prep.reference, coverage=cfg.coverage)
        tests = {g: s[1] for g, s in prep.sets.items()}
        kinds = {g: ev.kinds_of(t, prep.frame) for g, t in tests.items()}
        return PipelineResult(cfg, prep.choices, prep.reference, models, metrics, held_out, mini, tests, kinds,
                              prep.domain, dict(data.hashes))

    # ------------------------------------------------------------------------------------------------ helpers

    def _domain(self, frame: pd.DataFrame) -> tuple[pd.DataFrame, dict[str, int]]:
        settled = ev.after_settling(frame, self.config.settle_steps)
        domain = ev.in_domain(frame, self.config.min_pi1)
        mask = settled & domain
        return frame.loc[mask], {"rows": len(frame), "rows_used": int(mask.sum()),
                                 "rows_settling": int((~settled).sum()),
                                 "rows_outside_domain": int((settled & ~domain).sum())}

    def _overrides(self, spec: ModelSpec) -> dict[str, Any]:
        out: dict[str, Any] = {"rel_eps": self.config.rel_eps}
        if spec.cls not in ("DirectPi", "PowerLaw"):
            out.update(seed=self.config.seed, threads=self.config.threads)
        return {k: v for k, v in out.items() if k not in spec.config}

    @staticmethod
    def _split(frame: pd.DataFrame, choice: GroupChoice, ref_index: Any,
               test_keys: set[str]) -> tuple[DeltaDataset, DeltaDataset]:
        ds = DeltaDataset.from_recordings(frame, choice.output, choice.inputs, reference_index=[ref_index], warn=False)
        is_test = ev.episode_mask(ds, test_keys)
        return ds.subset(~is_test), ds.subset(is_test)

    def _held_out(self, model: DeltaModel, reference: pd.Series, frame: pd.DataFrame) -> dict[str, dict[str, Any]]:
        output, inputs = model_groups(model)
        out = {}
        for machine in ev.machines(frame):
            rows = frame[frame["machine"].astype(str) == machine]
            pairs = DeltaDataset.from_pairs(reference, rows, output, inputs, warn=False)
            out[machine] = ev.machine_metrics(model, pairs, self.config.coverage)
        return out


def with_models(config: PipelineConfig, names: Sequence[str] | None = None, **overrides: Any) -> PipelineConfig:
    """``config`` restricted to the models in ``names``, with other fields replaced by ``overrides``."""
    return replace(config, models=model_specs(names, config.models), **overrides)
