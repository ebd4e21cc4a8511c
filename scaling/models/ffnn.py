"""Feed-forward network for ln δ1 = f(g_2..g_n): the paper's best model (R² 0.99 on δ1 with the Eq. 10 groups)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from scaling.data.delta_dataset import DeltaDataset
from scaling.models import _torch as T
from scaling.models.base import Data


class FFNN(T.StandardisedNetModel):
    """MLP on standardised features predicting standardised ln δ1; Adam, early stopping on held-out episodes.

    Args:
        hidden_layers, units, dropout, activation: architecture (``hidden_layers`` × ``units``).
        lr, epochs, batch_size, weight_decay, patience: training (``batch_size`` ≥ n gives full-batch Adam).
        val_fraction: fraction of training *episodes* held out for early stopping (0: none, train loss decides).
        seed: seeds initialisation, dropout, shuffling and the validation split.
        threads: torch intra-op threads during fit/predict (default 1: small nets are fastest single-threaded and
            do not fight other processes for cores; ``None`` leaves torch's setting).
    """

    name = "FFNN"
    n_outputs = 1

    def __init__(self, *, hidden_layers: int = 2, units: int = 32, dropout: float = 0.0, activation: str = "silu",
                 lr: float = 3e-3, epochs: int = 300, batch_size: int = 2048, weight_decay: float = 0.0,
                 patience: int = 25, val_fraction: float = 0.15, seed: int = 0, threads: int | None = 1,
                 **base: Any) -> None:
        super().__init__(**base)
        if hidden_layers < 0 or units < 1 or not 0 <= dropout < 1:
            raise ValueError(f"bad architecture: hidden_layers={hidden_layers}, units={units}, dropout={dropout}")
        self.hidden_layers, self.units, self.dropout, self.activation = hidden_layers, units, dropout, activation
        self.lr, self.epochs, self.batch_size = lr, epochs, batch_size
        self.weight_decay, self.patience, self.val_fraction = weight_decay, patience, val_fraction
        self.seed, self.threads = seed, threads
        self.net_: torch.nn.Module | None = None
        self.x_scale_: T.Standardiser | None = None
        self.y_scale_: T.Standardiser | None = None
        self.log_: T.TrainLog | None = None

    def get_config(self) -> dict[str, Any]:
        keys = ("hidden_layers", "units", "dropout", "activation", "lr", "epochs", "batch_size", "weight_decay",
                "patience", "val_fraction", "seed", "threads")
        return {**super().get_config(), **{k: getattr(self, k) for k in keys}}

    def train_config(self) -> T.TrainConfig:
        return T.TrainConfig(lr=self.lr, epochs=self.epochs, batch_size=self.batch_size,
                             weight_decay=self.weight_decay, patience=self.patience)

    def _build(self, n_in: int) -> torch.nn.Module:
        return T.make_mlp(n_in, self.n_outputs, self.hidden_layers, self.units, self.dropout, self.activation)

    def _loss(self) -> T.LossFn:
        return T.mse_loss

    def _fit(self, dataset: DeltaDataset) -> None:
        train, val = T.validation_split(dataset, self.val_fraction, self.seed)
        x, y = self.features(train), train.log_delta
        self.x_scale_, self.y_scale_ = T.Standardiser.fit(x), T.Standardiser.fit(y)
        with T.seeded(self.seed, self.threads):
            self.net_ = self._build(x.shape[1])
            self.log_ = T.train_net(self.net_, self._loss(), self._tensors(x, y),
                                    None if val is None else self._tensors(self.features(val), val.log_delta),
                                    self.train_config())

    def _tensors(self, x: np.ndarray, y: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        assert self.x_scale_ is not None and self.y_scale_ is not None
        return T.to_tensor(self.x_scale_.apply(x)), T.to_tensor(self.y_scale_.apply(y.reshape(-1, 1)).ravel())

    def _raw_output(self, data: Data) -> np.ndarray:
        """Network output in standardised units, shape ``(n, n_outputs)``."""
        assert self.net_ is not None and self.x_scale_ is not None
        x = T.to_tensor(self.x_scale_.apply(self._x(data)))
        self.net_.eval()
        with torch.no_grad(), T.num_threads(self.threads):
            return self.net_(x).double().numpy().reshape(len(x), -1)

    def _predict_log(self, data: Data) -> np.ndarray:
        assert self.y_scale_ is not None
        return self.y_scale_.invert(self._raw_output(data)[:, 0])

    def _summary(self) -> str:
        n_par = sum(p.numel() for p in self.net_.parameters()) if self.net_ is not None else 0
        log = self.log_
        trained = (f"best epoch {log.best_epoch + 1}/{log.epochs_run}, monitored loss {log.best_val_loss:.4g}"
                   if log is not None else "loaded from disk")
        return f"MLP {self.hidden_layers}×{self.units} ({n_par} parameters); {trained}"
