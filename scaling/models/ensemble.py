"""Deep ensemble of Gaussian MLPs: predictive mean and variance of ln δ1, hence intervals on δ1 and on the target.

Each member outputs a mean and a log-variance of ln δ1 and is trained with the Gaussian negative log-likelihood
(Lakshminarayanan et al. 2017). The ensemble's predictive distribution of ln δ1 is the equal-weight mixture, summarised
by its mean μ and variance σ² = mean_k(σ_k² + μ_k²) − μ²; a central interval at coverage c is
``exp(μ ± z σ)`` on δ1 with z the (1+c)/2 normal quantile. Because F21_target = F31_target·π_1(source)/δ1 (Eq. 22)
is decreasing in δ1, the δ1 bounds swap on the target.
"""

from __future__ import annotations

from statistics import NormalDist
from typing import Any

import numpy as np
import torch

from scaling.data.delta_dataset import DeltaDataset
from scaling.models import _torch as T
from scaling.models.base import Data, DeltaModel
from scaling.models.ffnn import FFNN


class GaussianFFNN(FFNN):
    """One ensemble member: an :class:`FFNN` with (mean, log-variance) heads and a Gaussian NLL loss."""

    name = "GaussianFFNN"
    n_outputs = 2

    def _loss(self) -> T.LossFn:
        return T.gaussian_nll

    def _predict_log(self, data: Data) -> np.ndarray:
        return self.predict_log_dist(data)[0]

    def predict_log_dist(self, data: Data) -> tuple[np.ndarray, np.ndarray]:
        """(mean, variance) of ln δ1 in natural units."""
        assert self.y_scale_ is not None
        out = self._raw_output(data)
        var = np.exp(np.clip(out[:, 1], -12.0, 8.0)) * float(self.y_scale_.std[0]) ** 2
        return self.y_scale_.invert(out[:, 0]), var


class DeepEnsemble(DeltaModel):
    """K :class:`GaussianFFNN` members with seeds ``seed + k``; all keyword arguments but ``k`` go to the members."""

    name = "DeepEnsemble"

    def __init__(self, *, k: int = 5, rel_eps: float = 1e-3, include_source: bool = False,
                 **member_config: Any) -> None:
        super().__init__(rel_eps=rel_eps, include_source=include_source)
        if k < 1:
            raise ValueError(f"k must be >= 1, got {k}")
        self.k = k
        self.member_config = member_config
        self.members_: list[GaussianFFNN] = self._new_members()

    def _new_members(self) -> list[GaussianFFNN]:
        cfg = dict(self.member_config)
        seed = int(cfg.pop("seed", 0))
        return [GaussianFFNN(seed=seed + i, rel_eps=self.rel_eps, include_source=self.include_source, **cfg)
                for i in range(self.k)]

    def get_config(self) -> dict[str, Any]:
        return {**super().get_config(), "k": self.k, **self.member_config}

    def _fit(self, dataset: DeltaDataset) -> None:
        self.members_ = self._new_members()
        for m in self.members_:
            m.fit(dataset)

    def predict_log_dist(self, data: Data) -> tuple[np.ndarray, np.ndarray]:
        """Predictive (mean, variance) of ln δ1: the moments of the members' equal-weight Gaussian mixture."""
        self._require_fitted()
        x = self._x(data)
        dists = [m.predict_log_dist(x) for m in self.members_]
        means = np.stack([d[0] for d in dists])
        second = np.stack([d[1] + d[0] ** 2 for d in dists]).mean(axis=0)
        mean = means.mean(axis=0)
        return mean, np.maximum(second - mean**2, 0.0)

    def _predict_log(self, data: Data) -> np.ndarray:
        return self.predict_log_dist(data)[0]

    def predict_interval(self, data: Data, coverage: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
        """Central interval (lower, upper) on δ1 holding ``coverage`` of the predictive probability."""
        if not 0 < coverage < 1:
            raise ValueError(f"coverage must be in (0, 1), got {coverage}")
        z = NormalDist().inv_cdf(0.5 + coverage / 2)
        mean, var = self.predict_log_dist(data)
        half = z * np.sqrt(var)
        return np.exp(mean - half), np.exp(mean + half)

    def predict_target_interval(self, dataset: DeltaDataset, coverage: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
        """Interval on the target's scaled variable (e.g. F21_target, N) from the δ1 interval via Eq. 22."""
        lo, hi = self.predict_interval(dataset, coverage)
        a, b = dataset.recover(lo), dataset.recover(hi)
        return np.minimum(a, b), np.maximum(a, b)

    def _summary(self) -> str:
        epochs = [m.log_.best_epoch + 1 for m in self.members_ if m.log_ is not None]
        return f"{self.k} Gaussian MLP members; best epochs {epochs or 'n/a (loaded)'}"

    def _extra(self) -> dict[str, Any]:
        return {"members": [m._extra() for m in self.members_]}

    def _load_extra(self, extra: dict[str, Any]) -> None:
        self.members_ = self._new_members()
        for m, e in zip(self.members_, extra["members"], strict=True):
            m.groups_ = self.groups_
            m._load_extra(e)

    def _state(self) -> dict[str, torch.Tensor]:
        return {f"m{i}.{k}": v for i, m in enumerate(self.members_) for k, v in m._state().items()}

    def _load_state(self, state: dict[str, torch.Tensor]) -> None:
        for i, m in enumerate(self.members_):
            prefix = f"m{i}."
            m._load_state({k[len(prefix):]: v for k, v in state.items() if k.startswith(prefix)})
            m.transform_ = self.transform_
