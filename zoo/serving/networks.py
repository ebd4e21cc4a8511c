"""The network pieces the serving kernels share: NumPy activations for the one-row path, the bare-``addmm`` torch
forward of an MLP for the batch path, and the standardisers of a single-network model."""

from __future__ import annotations

import numpy as np
import torch
from scipy.special import expit
from torch import nn

from scaling.models import GRUModel
from scaling.models.ffnn import FFNN


def _silu(x: np.ndarray) -> np.ndarray:
    return x * expit(x)  # one ufunc for the logistic: a third of x / (1 + exp(-x))'s cost on a 64-wide row


def _relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0.0)


NUMPY_ACTIVATIONS = {"silu": _silu, "tanh": np.tanh, "relu": _relu}


def linears(net: nn.Module) -> list[tuple[np.ndarray, np.ndarray]]:
    return [(m.weight.detach().double().numpy().T.copy(), m.bias.detach().double().numpy().copy())
            for m in net.modules() if isinstance(m, nn.Linear)]


#: In-place torch activations of the batch path (gelu has no in-place form: it allocates).
TORCH_INPLACE = {"silu": lambda h: torch.nn.functional.silu(h, inplace=True), "tanh": torch.tanh_,
                 "relu": torch.relu_, "gelu": torch.nn.functional.gelu}


class TorchMLP:
    """The forward pass of a ``make_mlp`` network (Linear → activation [→ Dropout, identity at inference]) as bare
    ``addmm`` calls on the network's own float32 weights with in-place activations: the same arithmetic as
    ``net(z)`` (``F.linear`` is ``addmm`` with the transposed weight) without the module dispatch and with fewer
    temporaries."""

    def __init__(self, net: nn.Module, x_mean: np.ndarray, x_std: np.ndarray, activation: str) -> None:
        self.x_mean, self.x_std = x_mean, x_std
        self.layers = [(m.weight.detach().t(), m.bias.detach()) for m in net.modules() if isinstance(m, nn.Linear)]
        self.act = TORCH_INPLACE[activation]

    def __call__(self, g: np.ndarray) -> np.ndarray:
        """Network output (n, n_out) float64 of raw feature rows ``g`` (n, k), in one pass (callers chunk)."""
        z = np.ascontiguousarray((g - self.x_mean) / self.x_std, dtype=np.float32)
        with torch.inference_mode():
            h = torch.from_numpy(z)
            for w, b in self.layers[:-1]:
                h = self.act(torch.addmm(b, h, w))
            w, b = self.layers[-1]
            return torch.addmm(b, h, w).double().numpy()


class SingleNet:
    """A model with one network and its input/output standardisers (FFNN, GRU)."""

    def __init__(self, model: FFNN | GRUModel) -> None:
        assert model.net_ is not None and model.x_scale_ is not None and model.y_scale_ is not None
        self.net = model.net_.eval()
        self.x_mean, self.x_std = model.x_scale_.mean.astype(float), model.x_scale_.std.astype(float)
        self.y_mean, self.y_std = float(model.y_scale_.mean[0]), float(model.y_scale_.std[0])


__all__ = ["NUMPY_ACTIVATIONS", "TORCH_INPLACE", "SingleNet", "TorchMLP", "linears"]
