"""The δ1 model interface: ``fit(dataset) / predict(X or dataset) / score(dataset) -> R²`` and safe persistence.

Every model learns ``ln δ1 = f(g_2..g_n)`` where δ1 = π_1(source)/π_1(target) (paper Eq. 16/20; source = the
calibrated machine, the paper's "model"; target = the machine to predict, the paper's "prototype") and g_n are the
generalised log distortions of :class:`scaling.dimensions.factors.LogDistortion` (≈ ln d_n). ``predict`` returns δ1
itself.

Persistence: ``save(dir)`` writes ``config.json`` (class, hyper-parameters, groups, feature transform) and
``weights.safetensors`` (tensors only); ``load_model(dir)`` rebuilds the model. No pickle anywhere.
"""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
from safetensors.torch import load_file, save_file

from scaling.data.delta_dataset import DeltaDataset
from scaling.dimensions.factors import LogDistortion

CONFIG_FILE = "config.json"
WEIGHTS_FILE = "weights.safetensors"
FORMAT_VERSION = 1

_REGISTRY: dict[str, type[DeltaModel]] = {}

Data = DeltaDataset | np.ndarray


def r2_score(actual: np.ndarray, predicted: np.ndarray) -> float:
    """Coefficient of determination ``1 − SS_res/SS_tot`` (``nan`` if the actual values are constant)."""
    a, p = np.asarray(actual, dtype=float).ravel(), np.asarray(predicted, dtype=float).ravel()
    ss_tot = float(np.sum((a - a.mean()) ** 2))
    return float("nan") if ss_tot == 0 else 1.0 - float(np.sum((a - p) ** 2)) / ss_tot


class DeltaModel(ABC):
    """A strategy that learns the prediction factor δ1 from distortions; describes itself like an sklearn estimator.

    Subclasses set ``name``, accept their hyper-parameters as keyword arguments (returned by :meth:`get_config`),
    and implement :meth:`_fit`, :meth:`_predict_log`, :meth:`_state` / :meth:`_load_state` and :meth:`_summary`.
    """

    name: ClassVar[str] = "DeltaModel"

    def __init__(self, *, rel_eps: float = 1e-3, include_source: bool = False) -> None:
        self.rel_eps = rel_eps
        self.include_source = include_source
        self.transform_: LogDistortion | None = None
        self.groups_: dict[str, Any] | None = None

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        _REGISTRY[cls.name] = cls

    # ------------------------------------------------------------------------------------------- public API

    def get_config(self) -> dict[str, Any]:
        """Hyper-parameters (JSON-serialisable); ``type(model)(**model.get_config())`` is an unfitted copy."""
        return {"rel_eps": self.rel_eps, "include_source": self.include_source}

    @property
    def fitted(self) -> bool:
        return self.transform_ is not None

    def fit(self, dataset: DeltaDataset) -> DeltaModel:
        """Fit the feature transform (ε_n, s_n) and the model on a labelled data set; returns ``self``."""
        if not dataset.labelled or len(dataset) == 0:
            raise ValueError("fit needs a non-empty labelled DeltaDataset")
        pis = np.vstack([dataset.pi_source, dataset.pi_target])
        self.transform_ = LogDistortion(self.rel_eps, self.include_source).fit(pis)
        self.groups_ = dataset.groups_dict()
        try:
            self._fit(dataset)
        except BaseException:
            self.transform_ = None  # a failed fit leaves the model unfitted
            raise
        return self

    def features(self, dataset: DeltaDataset) -> np.ndarray:
        """Model inputs X (generalised log distortions), shape ``(n, n_features)``."""
        self._require_fitted()
        if dataset.groups_dict() != self.groups_:
            raise ValueError("the data set's groups differ from those the model was fitted on")
        assert self.transform_ is not None
        return self.transform_.transform(dataset.pi_source, dataset.pi_target)

    def predict_log(self, data: Data) -> np.ndarray:
        """Predicted ln δ1; ``data`` is a :class:`DeltaDataset` or a feature array X from :meth:`features`."""
        self._require_fitted()
        return self._predict_log(data)

    def predict(self, data: Data) -> np.ndarray:
        """Predicted prediction factor δ1 = π_1(source)/π_1(target), shape ``(n,)``."""
        return np.exp(self.predict_log(data))

    def predict_target(self, dataset: DeltaDataset) -> np.ndarray:
        """Predicted target value of the scaled variable (e.g. F21_target = F31_target·π_1(source)/δ1, Eq. 22)."""
        return dataset.recover(self.predict(dataset))

    def score(self, dataset: DeltaDataset) -> float:
        """R² of the predicted δ1 against the actual δ1 (the paper's Fig. 6/7 metric)."""
        return r2_score(dataset.delta, self.predict(dataset))

    def describe(self) -> str:
        """A readable summary: the model, its hyper-parameters, the groups and what was learnt."""
        cfg = ", ".join(f"{k}={v!r}" for k, v in self.get_config().items())
        lines = [f"{self.name}({cfg})", "  learns ln δ1 = f(g_2..g_n), δ1 = π1(source)/π1(target)"]
        if self.groups_ is not None:
            lines.append(f"  π1 = {self.groups_['output']['expression']}; inputs: "
                         + ", ".join(g["expression"] for g in self.groups_["inputs"]))
        lines.append("  " + (self._summary() if self.fitted else "not fitted"))
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"{self.name}({', '.join(f'{k}={v!r}' for k, v in self.get_config().items())})"

    # ------------------------------------------------------------------------------------------- persistence

    def state_dict(self) -> dict[str, torch.Tensor]:
        """All fitted numbers as tensors (feature transform included)."""
        self._require_fitted()
        assert self.transform_ is not None and self.transform_.eps is not None and self.transform_.sign is not None
        state = {"transform.eps": torch.from_numpy(self.transform_.eps.copy()),
                 "transform.sign": torch.from_numpy(self.transform_.sign.copy())}
        state.update({f"model.{k}": v.detach().cpu().contiguous() for k, v in self._state().items()})
        return state

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        self.transform_ = LogDistortion(self.rel_eps, self.include_source,
                                        eps=state["transform.eps"].numpy().astype(float),
                                        sign=state["transform.sign"].numpy().astype(float))
        self._load_state({k[len("model."):]: v for k, v in state.items() if k.startswith("model.")})

    def save(self, directory: str | Path) -> Path:
        """Write ``config.json`` + ``weights.safetensors`` into ``directory`` (created); returns the directory."""
        path = Path(directory)
        path.mkdir(parents=True, exist_ok=True)
        meta = {"format_version": FORMAT_VERSION, "class": self.name, "config": self.get_config(),
                "groups": self.groups_, "extra": self._extra()}
        (path / CONFIG_FILE).write_text(json.dumps(meta, indent=2, sort_keys=True))
        save_file(self.state_dict(), str(path / WEIGHTS_FILE))
        return path

    # ------------------------------------------------------------------------------------------- for subclasses

    @abstractmethod
    def _fit(self, dataset: DeltaDataset) -> None: ...

    @abstractmethod
    def _predict_log(self, data: Data) -> np.ndarray: ...

    def _state(self) -> dict[str, torch.Tensor]:
        return {}

    def _load_state(self, state: dict[str, torch.Tensor]) -> None:  # noqa: B027 - optional hook
        pass

    def _extra(self) -> dict[str, Any]:
        """JSON-serialisable fitted metadata (not tensors), restored by :meth:`_load_extra`."""
        return {}

    def _load_extra(self, extra: dict[str, Any]) -> None:  # noqa: B027 - optional hook
        pass

    def _summary(self) -> str:
        return "fitted"

    def _x(self, data: Data) -> np.ndarray:
        return self.features(data) if isinstance(data, DeltaDataset) else np.asarray(data, dtype=float)

    def _require_fitted(self) -> None:
        if not self.fitted:
            raise RuntimeError(f"{self.name} is not fitted; call fit(dataset) first")


def model_class(name: str) -> type[DeltaModel]:
    """The model class registered under ``name`` (its ``DeltaModel.name``), e.g. ``"FFNN"``."""
    if name not in _REGISTRY:
        raise ValueError(f"unknown model class {name!r}; known: {sorted(_REGISTRY)}")
    return _REGISTRY[name]


def load_model(directory: str | Path) -> DeltaModel:
    """Rebuild a model written by :meth:`DeltaModel.save` (JSON + safetensors only)."""
    path = Path(directory)
    meta = json.loads((path / CONFIG_FILE).read_text())
    if meta.get("format_version") != FORMAT_VERSION:
        raise ValueError(f"unsupported model format {meta.get('format_version')!r}")
    model = model_class(meta["class"])(**meta["config"])
    model.groups_ = meta["groups"]
    model._load_extra(meta.get("extra", {}))
    model.load_state_dict(load_file(str(path / WEIGHTS_FILE)))
    return model
