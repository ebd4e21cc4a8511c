"""Recurrent (GRU) model of ln δ1 over each dig cycle, keeping the time order (paper §2.6; R² 0.81–0.85).

A sequence is one (reference row, machine, episode), ordered by ``t``. Training uses whole sequences (padded and
masked) or, with ``window``, overlapping truncated windows; windows that do not start at the beginning of their
sequence ignore their first ``burn_in`` steps in the loss, so the hidden state has warmed up where it is scored.
Prediction always runs each full sequence from its start.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

from scaling.data.delta_dataset import DeltaDataset
from scaling.models import _torch as T
from scaling.models.base import Data


class _GRUNet(nn.Module):
    def __init__(self, n_in: int, hidden: int, layers: int, dropout: float) -> None:
        super().__init__()
        self.gru = nn.GRU(n_in, hidden, num_layers=layers, batch_first=True, dropout=dropout if layers > 1 else 0.0)
        self.head = nn.Linear(hidden, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.gru(x)[0]).squeeze(-1)


def _windows(seqs: list[np.ndarray], window: int | None, stride: int, burn_in: int) -> list[tuple[np.ndarray, int]]:
    """(row indices, first scored position) per training window."""
    if window is None:
        return [(s, 0) for s in seqs]
    out = []
    for s in seqs:
        starts = range(0, max(1, len(s) - window + stride), stride)
        out += [(s[a:a + window], 0 if a == 0 else min(burn_in, window - 1)) for a in starts if a < len(s)]
    return out


def _pad(x: np.ndarray, y: np.ndarray | None, wins: list[tuple[np.ndarray, int]]) -> tuple[torch.Tensor, ...]:
    """Batch tensors (x: (B, L, k), y: (B, L), mask: (B, L)) padded with zeros after each window's end."""
    length = max(len(w) for w, _ in wins)
    xb = np.zeros((len(wins), length, x.shape[1]), dtype=np.float32)
    yb = np.zeros((len(wins), length), dtype=np.float32)
    mask = np.zeros((len(wins), length), dtype=np.float32)
    for i, (w, first) in enumerate(wins):
        xb[i, :len(w)] = x[w]
        if y is not None:
            yb[i, :len(w)] = y[w]
        mask[i, first:len(w)] = 1.0
    return torch.from_numpy(xb), torch.from_numpy(yb), torch.from_numpy(mask)


class GRUModel(T.StandardisedNetModel):
    """GRU over time-ordered distortion features of each episode, predicting ln δ1 at every step.

    Args:
        hidden_size, num_layers, dropout: recurrent architecture (dropout between GRU layers).
        window, stride, burn_in: truncated training windows (``window=None``: whole sequences).
        lr, epochs, batch_size (windows per step), weight_decay, patience, val_fraction, seed, threads: as FFNN.
    """

    name = "GRUModel"

    def __init__(self, *, hidden_size: int = 32, num_layers: int = 1, dropout: float = 0.0,
                 window: int | None = None, stride: int | None = None, burn_in: int = 10, lr: float = 1e-2,
                 epochs: int = 200, batch_size: int = 64, weight_decay: float = 0.0, patience: int = 25,
                 val_fraction: float = 0.15, seed: int = 0, threads: int | None = 1, **base: Any) -> None:
        super().__init__(**base)
        if window is not None and window < 2:
            raise ValueError(f"window must be >= 2 or None, got {window}")
        self.hidden_size, self.num_layers, self.dropout = hidden_size, num_layers, dropout
        self.window, self.stride, self.burn_in = window, stride, burn_in
        self.lr, self.epochs, self.batch_size = lr, epochs, batch_size
        self.weight_decay, self.patience, self.val_fraction = weight_decay, patience, val_fraction
        self.seed, self.threads = seed, threads
        self.net_: _GRUNet | None = None
        self.x_scale_: T.Standardiser | None = None
        self.y_scale_: T.Standardiser | None = None
        self.log_: T.TrainLog | None = None

    def get_config(self) -> dict[str, Any]:
        keys = ("hidden_size", "num_layers", "dropout", "window", "stride", "burn_in", "lr", "epochs",
                "batch_size", "weight_decay", "patience", "val_fraction", "seed", "threads")
        return {**super().get_config(), **{k: getattr(self, k) for k in keys}}

    def _batch(self, dataset: DeltaDataset, windowed: bool) -> tuple[torch.Tensor, ...]:
        assert self.x_scale_ is not None and self.y_scale_ is not None
        x = self.x_scale_.apply(self.features(dataset))
        y = self.y_scale_.apply(dataset.log_delta.reshape(-1, 1)).ravel()
        stride = self.stride or max(1, (self.window or 2) // 2)
        return _pad(x, y, _windows(dataset.sequences(), self.window if windowed else None, stride, self.burn_in))

    def _fit(self, dataset: DeltaDataset) -> None:
        train, val = T.validation_split(dataset, self.val_fraction, self.seed)
        self.x_scale_ = T.Standardiser.fit(self.features(train))
        self.y_scale_ = T.Standardiser.fit(train.log_delta)
        cfg = T.TrainConfig(lr=self.lr, epochs=self.epochs, batch_size=self.batch_size,
                            weight_decay=self.weight_decay, patience=self.patience)
        with T.seeded(self.seed, self.threads):
            self.net_ = self._build(self.x_scale_.mean.shape[0])
            val_batch = None if val is None else self._batch(val, windowed=False)
            self.log_ = T.train_net(self.net_, T.mse_loss, self._batch(train, windowed=True), val_batch, cfg)

    def _build(self, n_in: int) -> _GRUNet:
        return _GRUNet(n_in, self.hidden_size, self.num_layers, self.dropout)

    def _run(self, xb: torch.Tensor) -> np.ndarray:
        assert self.net_ is not None and self.y_scale_ is not None
        self.net_.eval()
        with torch.no_grad(), T.num_threads(self.threads):
            return self.y_scale_.invert(self.net_(xb).double().numpy())

    def _predict_log(self, data: Data) -> np.ndarray:
        """ln δ1 per row of a data set (each sequence run from its start), or per step of X (T, k) / (B, T, k)."""
        assert self.x_scale_ is not None
        if not isinstance(data, DeltaDataset):
            x = np.asarray(data, dtype=float)
            xs = torch.as_tensor(self.x_scale_.apply(x), dtype=torch.float32)
            return self._run(xs[None] if x.ndim == 2 else xs)[0 if x.ndim == 2 else slice(None)]
        seqs = data.sequences()
        xb = _pad(self.x_scale_.apply(self.features(data)), None, [(s, 0) for s in seqs])[0]
        out, pred = self._run(xb), np.empty(len(data))
        for i, s in enumerate(seqs):
            pred[s] = out[i, :len(s)]
        return pred

    def _summary(self) -> str:
        log = self.log_
        trained = f"best epoch {log.best_epoch + 1}/{log.epochs_run}" if log is not None else "loaded from disk"
        return f"GRU {self.num_layers}×{self.hidden_size}, window={self.window}; {trained}"
