"""Shared torch plumbing for the neural δ1 models: standardisation, MLPs, seeded Adam training with early stopping."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torch import nn

from scaling.data.delta_dataset import DeltaDataset
from scaling.models.base import DeltaModel

LossFn = Callable[[torch.Tensor, torch.Tensor, torch.Tensor | None], torch.Tensor]

ACTIVATIONS: dict[str, type[nn.Module]] = {"silu": nn.SiLU, "tanh": nn.Tanh, "relu": nn.ReLU, "gelu": nn.GELU}


@dataclass
class Standardiser:
    """Affine map ``(x − mean)/std`` per column; ``std`` of a constant column is 1 (never divides by 0)."""

    mean: np.ndarray
    std: np.ndarray

    @classmethod
    def fit(cls, x: np.ndarray) -> Standardiser:
        x2 = np.asarray(x, dtype=float).reshape(len(x), -1)
        std = x2.std(axis=0)
        return cls(x2.mean(axis=0), np.where(std > 1e-12, std, 1.0))

    def apply(self, x: np.ndarray) -> np.ndarray:
        return (np.asarray(x, dtype=float) - self.mean) / self.std

    def invert(self, z: np.ndarray) -> np.ndarray:
        return np.asarray(z, dtype=float) * self.std + self.mean

    def state(self, prefix: str) -> dict[str, torch.Tensor]:
        return {f"{prefix}.mean": torch.from_numpy(np.atleast_1d(self.mean).astype(np.float64)),
                f"{prefix}.std": torch.from_numpy(np.atleast_1d(self.std).astype(np.float64))}

    @classmethod
    def from_state(cls, state: dict[str, torch.Tensor], prefix: str) -> Standardiser:
        return cls(state[f"{prefix}.mean"].numpy().astype(float), state[f"{prefix}.std"].numpy().astype(float))


def make_mlp(n_in: int, n_out: int, hidden_layers: int, units: int, dropout: float, activation: str) -> nn.Sequential:
    """``hidden_layers`` × (Linear → activation → Dropout) then a linear head of width ``n_out``."""
    if activation not in ACTIVATIONS:
        raise ValueError(f"unknown activation {activation!r}; choose from {sorted(ACTIVATIONS)}")
    layers: list[nn.Module] = []
    width = n_in
    for _ in range(hidden_layers):
        layers += [nn.Linear(width, units), ACTIVATIONS[activation]()]
        if dropout > 0:
            layers.append(nn.Dropout(dropout))
        width = units
    layers.append(nn.Linear(width, n_out))
    return nn.Sequential(*layers)


@contextlib.contextmanager
def num_threads(threads: int | None) -> Iterator[None]:
    """Run a block with ``threads`` torch intra-op threads (``None``: unchanged); restores the old setting."""
    old = torch.get_num_threads()
    if threads:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        if threads:
            torch.set_num_threads(old)


@contextlib.contextmanager
def seeded(seed: int, threads: int | None = None) -> Iterator[None]:
    """Deterministic block: torch's CPU RNG forked (the caller's RNG state is untouched) and seeded."""
    with torch.random.fork_rng(devices=[]), num_threads(threads):
        torch.manual_seed(seed)
        yield


def mse_loss(pred: torch.Tensor, y: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    err = (pred.reshape(y.shape) - y) ** 2
    return err.mean() if mask is None else (err * mask).sum() / mask.sum().clamp_min(1.0)


def gaussian_nll(out: torch.Tensor, y: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Gaussian negative log-likelihood (constant dropped) for ``out[..., 0]`` = mean, ``out[..., 1]`` = log σ²."""
    mean, log_var = out[..., 0], out[..., 1].clamp(-12.0, 8.0)
    nll = 0.5 * (log_var + (y.reshape(mean.shape) - mean) ** 2 / log_var.exp())
    return nll.mean() if mask is None else (nll * mask).sum() / mask.sum().clamp_min(1.0)


@dataclass
class TrainConfig:
    """Adam with mini-batches (``batch_size`` ≥ n means full batch) and early stopping on a validation loss."""

    lr: float = 3e-3
    epochs: int = 300
    batch_size: int = 2048
    weight_decay: float = 0.0
    patience: int = 25
    min_delta: float = 1e-5


@dataclass
class TrainLog:
    best_epoch: int = -1
    epochs_run: int = 0
    best_val_loss: float = float("inf")
    train_loss: list[float] = field(default_factory=list)
    val_loss: list[float] = field(default_factory=list)


Batch = tuple[torch.Tensor, ...]


def train_net(net: nn.Module, loss_fn: LossFn, train: Batch, val: Batch | None, cfg: TrainConfig) -> TrainLog:
    """Fit ``net`` on tensors ``(x, y[, mask])``; restores the weights of the best validation epoch.

    Without a validation set the training loss drives early stopping. Shuffling uses torch's (seeded) RNG.
    """
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    n = train[0].shape[0]
    bs = max(1, min(cfg.batch_size, n))
    log, best_state, stale = TrainLog(), None, 0
    for epoch in range(cfg.epochs):
        net.train()
        perm = torch.randperm(n) if bs < n else torch.arange(n)
        total = 0.0
        for start in range(0, n, bs):
            idx = perm[start:start + bs]
            opt.zero_grad(set_to_none=True)
            loss = _loss(net, loss_fn, tuple(t[idx] for t in train))
            loss.backward()
            opt.step()
            total += float(loss.detach()) * len(idx)
        log.train_loss.append(total / n)
        monitor = log.train_loss[-1] if val is None else evaluate_loss(net, loss_fn, val)
        if val is not None:
            log.val_loss.append(monitor)
        log.epochs_run = epoch + 1
        if monitor < log.best_val_loss - cfg.min_delta:
            log.best_val_loss, log.best_epoch, stale = monitor, epoch, 0
            best_state = {k: v.detach().clone() for k, v in net.state_dict().items()}
        else:
            stale += 1
            if stale >= cfg.patience:
                break
    if best_state is not None:
        net.load_state_dict(best_state)
    net.eval()
    return log


def _loss(net: nn.Module, loss_fn: LossFn, batch: Batch) -> torch.Tensor:
    x, y, *rest = batch
    return loss_fn(net(x), y, rest[0] if rest else None)


def evaluate_loss(net: nn.Module, loss_fn: LossFn, batch: Batch) -> float:
    net.eval()
    with torch.no_grad():
        return float(_loss(net, loss_fn, batch))


def validation_split(dataset: DeltaDataset, fraction: float, seed: int) -> tuple[DeltaDataset, DeltaDataset | None]:
    """(train, validation) split by episode; no validation when ``fraction`` is 0 or there is a single episode."""
    if fraction <= 0 or len(np.unique(dataset.episode_keys())) < 2:
        return dataset, None
    return dataset.split_by_episode(fraction, seed)


def to_tensor(x: np.ndarray) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x, dtype=np.float32))


def net_state(net: nn.Module, prefix: str = "net") -> dict[str, torch.Tensor]:
    return {f"{prefix}.{k}": v for k, v in net.state_dict().items()}


def load_net_state(net: nn.Module, state: dict[str, torch.Tensor], prefix: str = "net") -> None:
    sub = {k[len(prefix) + 1:]: v for k, v in state.items() if k.startswith(prefix + ".")}
    net.load_state_dict(sub)
    net.eval()


class StandardisedNetModel(DeltaModel):
    """Shared persistence of the torch δ1 models: a network ``net_`` plus input/output standardisers, saved as
    safetensors tensors (``net.*``, ``x_scale.*``, ``y_scale.*``) and rebuilt from the input width."""

    net_: nn.Module | None
    x_scale_: Standardiser | None
    y_scale_: Standardiser | None
    seed: int

    def _build(self, n_in: int) -> nn.Module:
        raise NotImplementedError

    def _extra(self) -> dict[str, Any]:
        assert self.x_scale_ is not None
        return {"n_in": int(self.x_scale_.mean.shape[0])}

    def _load_extra(self, extra: dict[str, Any]) -> None:
        with seeded(self.seed):
            self.net_ = self._build(int(extra["n_in"]))

    def _state(self) -> dict[str, torch.Tensor]:
        assert self.net_ is not None and self.x_scale_ is not None and self.y_scale_ is not None
        return {**net_state(self.net_), **self.x_scale_.state("x_scale"), **self.y_scale_.state("y_scale")}

    def _load_state(self, state: dict[str, torch.Tensor]) -> None:
        assert self.net_ is not None
        load_net_state(self.net_, state)
        self.x_scale_ = Standardiser.from_state(state, "x_scale")
        self.y_scale_ = Standardiser.from_state(state, "y_scale")
