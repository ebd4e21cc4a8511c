"""Lean forward passes of the δ1 models, extracted once from a loaded :class:`scaling.models.DeltaModel`.

Everything here works on plain arrays in SI with no validation, so that one row costs a few microseconds:

* :class:`GroupPlan` evaluates the π groups (products of powers of columns) on a raw SI matrix or one row;
* :class:`Features` turns target group values into the model's generalised log distortions
  ``g_n = s_n·[asinh(π_n^s/2ε_n) − asinh(π_n^t/2ε_n)]`` (:class:`scaling.factors.LogDistortion`) for a fixed source;
* a kernel maps ``g`` to ln δ1 (and, for the ensemble, its predictive variance): :class:`MLPKernel` (FFNN),
  :class:`EnsembleKernel` (deep ensemble; members stacked for one batched matmul per layer) and :class:`GRUKernel`
  (recurrent; ``step`` carries the hidden state). ``row`` is the single-row NumPy path (float64); ``batch`` runs the
  model's own torch modules over cache-sized chunks in inference mode (float32, as trained).

δ1 = π1(source)/π1(target) as in :mod:`scaling.factors`; the kernels only compute ln δ1.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from scaling.groups import PiGroup
from scaling.models import DeepEnsemble, DeltaModel, GRUModel
from scaling.models.ffnn import FFNN
from zoo.serving.parallel import map_ordered

#: Rows per chunk of the batch path (keeps activations in cache).
CHUNK = 8192


def _silu(x: np.ndarray) -> np.ndarray:
    return x / (1.0 + np.exp(-x))


def _relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0.0)


NUMPY_ACTIVATIONS = {"silu": _silu, "tanh": np.tanh, "relu": _relu}


@dataclass(frozen=True)
class GroupPlan:
    """Groups as (column, exponent) terms over ``variables``; evaluates them on SI rows."""

    variables: tuple[str, ...]
    terms: tuple[tuple[tuple[int, float], ...], ...]

    @classmethod
    def build(cls, groups: Sequence[PiGroup], variables: Sequence[str]) -> GroupPlan:
        index = {v: i for i, v in enumerate(variables)}
        terms = tuple(tuple((index[k], float(e)) for k, e in g.exponents.items()) for g in groups)
        return cls(tuple(variables), terms)

    def values(self, x: np.ndarray) -> np.ndarray:
        """Group values on a matrix ``(n, len(variables))`` → ``(n, n_groups)``; inf/NaN where a divisor is 0."""
        out = np.empty((x.shape[0], len(self.terms)))
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            for j, terms in enumerate(self.terms):
                v = np.ones(x.shape[0])
                for col, e in terms:
                    v = v * x[:, col] if e == 1.0 else v / x[:, col] if e == -1.0 else v * np.power(x[:, col], e)
                out[:, j] = v
        return out

    def row(self, x: Sequence[float]) -> list[float]:
        """Group values of one row (plain floats; ``ZeroDivisionError`` where a divisor is 0)."""
        out = []
        for terms in self.terms:
            v = 1.0
            for col, e in terms:
                v = v * x[col] if e == 1.0 else v / x[col] if e == -1.0 else v * x[col] ** e
            out.append(v)
        return out


@dataclass(frozen=True)
class Features:
    """g = s·[asinh(π^s/2ε) − asinh(π^t/2ε)] for the fixed source group values ``pi_source`` (shape (k,) or (n, k))."""

    scale: np.ndarray  # 1/(2ε), (k,)
    sign: np.ndarray  # s_n, (k,)
    h_source: np.ndarray  # s·asinh(π^s/2ε), (k,) or (n, k)

    @classmethod
    def build(cls, eps: np.ndarray, sign: np.ndarray, pi_source: np.ndarray) -> Features:
        scale = 0.5 / np.asarray(eps, dtype=float)
        sign = np.asarray(sign, dtype=float)
        return cls(scale, sign, sign * np.arcsinh(np.asarray(pi_source, dtype=float) * scale))

    def __call__(self, pi_target: np.ndarray) -> np.ndarray:
        return self.h_source - self.sign * np.arcsinh(pi_target * self.scale)

    def rows(self, start: int, stop: int) -> Features:
        """The features of paired sources ``start:stop`` (``h_source`` of shape (n, k))."""
        return Features(self.scale, self.sign, self.h_source[start:stop])


def _linears(net: nn.Module) -> list[tuple[np.ndarray, np.ndarray]]:
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


class _SingleNet:
    """A model with one network and its input/output standardisers (FFNN, GRU)."""

    def __init__(self, model: FFNN | GRUModel) -> None:
        assert model.net_ is not None and model.x_scale_ is not None and model.y_scale_ is not None
        self.net = model.net_.eval()
        self.x_mean, self.x_std = model.x_scale_.mean.astype(float), model.x_scale_.std.astype(float)
        self.y_mean, self.y_std = float(model.y_scale_.mean[0]), float(model.y_scale_.std[0])


class MLPKernel(_SingleNet):
    """An :class:`FFNN`: standardise g, MLP, un-standardise → ln δ1."""

    def __init__(self, model: FFNN) -> None:
        super().__init__(model)
        self.layers = _linears(self.net)
        self.act = NUMPY_ACTIVATIONS.get(model.activation)
        self.torch_mlp = TorchMLP(self.net, self.x_mean, self.x_std, model.activation)

    def row(self, g: np.ndarray) -> float:
        """ln δ1 of one feature row ``g`` (k,)."""
        if self.act is None:
            return float(self.batch(g[None])[0][0])
        h = (g - self.x_mean) / self.x_std
        last = len(self.layers) - 1
        for i, (w, b) in enumerate(self.layers):
            h = h @ w + b
            if i < last:
                h = self.act(h)
        return self.y_mean + self.y_std * float(h[0])

    def batch(self, g: np.ndarray) -> tuple[np.ndarray, None]:
        """ln δ1 of feature rows ``g`` (n, k); no predictive variance."""
        return self.y_mean + self.y_std * self.torch_mlp(g)[:, 0], None


class EnsembleKernel:
    """A :class:`DeepEnsemble`: K Gaussian MLPs, each with its own standardisers; mixture mean and variance."""

    def __init__(self, model: DeepEnsemble) -> None:
        members = model.members_
        self.nets = [m.net_.eval() for m in members]
        self.x_mean = np.stack([m.x_scale_.mean for m in members]).astype(float)[:, None, :]
        self.x_std = np.stack([m.x_scale_.std for m in members]).astype(float)[:, None, :]
        self.y_mean = np.array([float(m.y_scale_.mean[0]) for m in members])
        self.y_std = np.array([float(m.y_scale_.std[0]) for m in members])
        per_member = [_linears(n) for n in self.nets]
        self.layers = [(np.stack([p[i][0] for p in per_member]), np.stack([p[i][1] for p in per_member])[:, None, :])
                       for i in range(len(per_member[0]))]
        self.act = NUMPY_ACTIVATIONS.get(members[0].activation)
        self.torch_mlps = [TorchMLP(net, self.x_mean[k, 0], self.x_std[k, 0], m.activation)
                           for k, (net, m) in enumerate(zip(self.nets, members, strict=True))]

    def _mixture(self, out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mean, variance) of ln δ1 from member outputs ``out`` (K, n, 2) in standardised units."""
        mu = self.y_mean[:, None] + self.y_std[:, None] * out[..., 0]
        var = np.exp(np.clip(out[..., 1], -12.0, 8.0)) * self.y_std[:, None] ** 2
        mean = mu.mean(axis=0)
        return mean, np.maximum((var + mu**2).mean(axis=0) - mean**2, 0.0)

    def row(self, g: np.ndarray) -> tuple[float, float]:
        """(mean, variance) of ln δ1 for one feature row."""
        if self.act is None:
            mean, var = self.batch(g[None])
            return float(mean[0]), float(var[0])
        h = (g[None, None, :] - self.x_mean) / self.x_std
        last = len(self.layers) - 1
        for i, (w, b) in enumerate(self.layers):
            h = np.matmul(h, w) + b
            if i < last:
                h = self.act(h)
        mean, var = self._mixture(h)
        return float(mean[0]), float(var[0])

    def batch(self, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mean, variance) of ln δ1 for feature rows ``g`` (n, k), one chunk at a time."""
        return self._mixture(np.stack([mlp(g) for mlp in self.torch_mlps]))


class GRUKernel(_SingleNet):
    """A :class:`GRUModel`: one step at a time (``step``, NumPy, hidden state carried) or whole sequences."""

    def __init__(self, model: GRUModel) -> None:
        super().__init__(model)
        gru = self.net.gru
        self.hidden, self.num_layers = gru.hidden_size, gru.num_layers
        self.cells = [tuple(getattr(gru, f"{n}_l{i}").detach().double().numpy().copy()
                            for n in ("weight_ih", "weight_hh", "bias_ih", "bias_hh")) for i in range(self.num_layers)]
        w, b = _linears(self.net.head)[0]
        self.head_w, self.head_b = w[:, 0], float(b[0])

    def initial_state(self) -> np.ndarray:
        return np.zeros((self.num_layers, self.hidden))

    def step(self, g: np.ndarray, state: np.ndarray) -> tuple[float, np.ndarray]:
        """ln δ1 at this step and the next hidden state (PyTorch's GRU equations, gates ordered r, z, n)."""
        x = (g - self.x_mean) / self.x_std
        new = np.empty_like(state)
        hdim = self.hidden
        for layer, (w_ih, w_hh, b_ih, b_hh) in enumerate(self.cells):
            h = state[layer]
            gi, gh = w_ih @ x + b_ih, w_hh @ h + b_hh
            rz = 1.0 / (1.0 + np.exp(-(gi[:2 * hdim] + gh[:2 * hdim])))
            n = np.tanh(gi[2 * hdim:] + rz[:hdim] * gh[2 * hdim:])
            x = new[layer] = n + rz[hdim:] * (h - n)
        return self.y_mean + self.y_std * (float(x @ self.head_w) + self.head_b), new

    def sequences(self, g: np.ndarray, seqs: Sequence[np.ndarray], threads: int = 1) -> np.ndarray:
        """ln δ1 of every row, each index array of ``seqs`` run as one sequence from a zero state.

        Sequences of equal length share one batched GRU call; with ``threads`` > 1 each such batch is split into
        ``threads`` parts run at once (the same results up to float32 rounding).
        """
        z = ((g - self.x_mean) / self.x_std).astype(np.float32)
        out = np.empty(len(g))
        by_length: dict[int, list[np.ndarray]] = {}
        for s in seqs:
            by_length.setdefault(len(s), []).append(np.asarray(s))
        parts = [part for group in by_length.values()
                 for part in np.array_split(np.stack(group), min(threads, len(group)))]

        def run(idx: np.ndarray) -> None:
            with torch.inference_mode():
                out[idx] = self.net(torch.from_numpy(z[idx])).double().numpy()

        map_ordered(run, parts, threads)
        return self.y_mean + self.y_std * out


Kernel = MLPKernel | EnsembleKernel | GRUKernel


def kernel_for(model: DeltaModel) -> Kernel:
    """The serving kernel of a fitted δ1 model (FFNN, DeepEnsemble or GRUModel).

    Raises:
        TypeError: another model class (e.g. PowerLaw, DirectPi): not served by the zoo.
    """
    if isinstance(model, DeepEnsemble):
        return EnsembleKernel(model)
    if isinstance(model, GRUModel):
        return GRUKernel(model)
    if isinstance(model, FFNN) and type(model).n_outputs == 1:
        return MLPKernel(model)
    raise TypeError(f"the zoo serves FFNN, GRUModel and DeepEnsemble δ1 models, not {model.name}")


def normal_quantile(coverage: float) -> float:
    """z of a central normal interval holding ``coverage``."""
    from statistics import NormalDist

    return NormalDist().inv_cdf(0.5 + coverage / 2)


__all__ = ["CHUNK", "EnsembleKernel", "Features", "GRUKernel", "GroupPlan", "Kernel", "MLPKernel", "kernel_for",
           "normal_quantile"]
