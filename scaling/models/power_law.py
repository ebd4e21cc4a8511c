"""Power law of the distortions: ``δ1 = e^b ∏ d_n^{a_n}``, fitted as ``ln δ1 = Σ a_n g_n + b`` by least squares."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from scaling.data.delta_dataset import DeltaDataset
from scaling.models.base import Data, DeltaModel

#: Features are clipped to [min − m·span, max + m·span] of the training features (m, dimensionless).
EXTRAPOLATION_MARGIN = 0.5


class PowerLaw(DeltaModel):
    """Log-linear least squares on the generalised log distortions g_n (≈ ln d_n).

    If π_1 = C·∏ π_n^{a_n} exactly, then δ1 = ∏ d_n^{a_n} and the fitted exponents are the a_n (b = 0).

    Predictions clip every feature to its training range widened by half its span on each side
    (:data:`EXTRAPOLATION_MARGIN`): a group that crosses zero (a cylinder force at the moment it changes sign) gives
    g_n far beyond anything fitted, and a log-linear law extrapolated there returns δ1 off by e^10 and more, while
    a modest step beyond the data (the law's purpose between machines) is kept.

    Args:
        ridge: L2 penalty on the exponents (0 = ordinary least squares); the intercept is not penalised.
        fit_intercept: fit b (otherwise b = 0, so all d_n = 1 gives δ1 = 1 exactly).
    """

    name = "PowerLaw"

    def __init__(self, *, ridge: float = 0.0, fit_intercept: bool = True, **base: Any) -> None:
        super().__init__(**base)
        if ridge < 0:
            raise ValueError(f"ridge must be >= 0, got {ridge}")
        self.ridge = ridge
        self.fit_intercept = fit_intercept
        self.coef_: np.ndarray | None = None
        self.intercept_: float = 0.0
        self.x_range_: tuple[np.ndarray, np.ndarray] | None = None

    def get_config(self) -> dict[str, Any]:
        return {**super().get_config(), "ridge": self.ridge, "fit_intercept": self.fit_intercept}

    def _fit(self, dataset: DeltaDataset) -> None:
        x, y = self.features(dataset), dataset.log_delta
        x_mean = x.mean(axis=0) if self.fit_intercept else np.zeros(x.shape[1])
        y_mean = float(y.mean()) if self.fit_intercept else 0.0
        xc, yc = x - x_mean, y - y_mean
        if self.ridge > 0:
            gram = xc.T @ xc + self.ridge * np.eye(x.shape[1])
            coef = np.linalg.solve(gram, xc.T @ yc)
        else:
            coef = np.linalg.lstsq(xc, yc, rcond=None)[0]
        self.coef_ = coef
        self.intercept_ = y_mean - float(x_mean @ coef)
        lo, hi = x.min(axis=0), x.max(axis=0)
        self.x_range_ = (lo - EXTRAPOLATION_MARGIN * (hi - lo), hi + EXTRAPOLATION_MARGIN * (hi - lo))

    def _predict_log(self, data: Data) -> np.ndarray:
        assert self.coef_ is not None
        x = self._x(data)
        if self.x_range_ is not None:
            x = np.clip(x, *self.x_range_)
        return x @ self.coef_ + self.intercept_

    def exponents(self) -> dict[str, float]:
        """Fitted exponent a_n per input group expression (and ``"source:..."`` terms with include_source)."""
        self._require_fitted()
        assert self.coef_ is not None and self.groups_ is not None
        names = [g["expression"] for g in self.groups_["inputs"]]
        if self.include_source:
            names += [f"source:{n}" for n in names]
        return dict(zip(names, (float(c) for c in self.coef_), strict=True))

    def _summary(self) -> str:
        exps = self.exponents()
        terms = " · ".join(f"d[{k}]^{a:+.4g}" for k, a in exps.items() if not k.startswith("source:"))
        text = f"δ1 = {np.exp(self.intercept_):.4g} · {terms}   (ln-intercept b = {self.intercept_:+.4g})"
        src = ", ".join(f"{k[len('source:'):]}: {a:+.4g}" for k, a in exps.items() if k.startswith("source:"))
        return text + (f"\n  source-level terms (coefficients of s·asinh(π^s/2ε)): {src}" if src else "")

    def _state(self) -> dict[str, torch.Tensor]:
        assert self.coef_ is not None
        state = {"coef": torch.from_numpy(self.coef_.astype(np.float64)),
                 "intercept": torch.tensor([self.intercept_], dtype=torch.float64)}
        if self.x_range_ is not None:
            state["x_lo"], state["x_hi"] = (torch.from_numpy(v.astype(np.float64)) for v in self.x_range_)
        return state

    def _load_state(self, state: dict[str, torch.Tensor]) -> None:
        self.coef_ = state["coef"].numpy().astype(float)
        self.intercept_ = float(state["intercept"][0])
        # models saved before the range was stored predict unclipped, as they did
        self.x_range_ = ((state["x_lo"].numpy().astype(float), state["x_hi"].numpy().astype(float))
                         if "x_lo" in state else None)
