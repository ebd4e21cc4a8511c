"""Lean forward passes of the δ1 models, extracted once from a loaded :class:`scaling.models.DeltaModel`.

Everything here works on plain arrays in SI with no validation, so that one row costs a few microseconds:

* :class:`GroupPlan` evaluates the π groups (products of powers of columns) on a raw SI matrix or one row;
* :class:`Features` turns target group values into the model's generalised log distortions
  ``g_n = s_n·[asinh(π_n^s/2ε_n) − asinh(π_n^t/2ε_n)]`` (:class:`scaling.dimensions.factors.LogDistortion`) for a fixed
  source (one row, or one per target row), followed by the source's own ``s_n·asinh(π_n^s/2ε_n)`` for a model fitted
  with ``include_source=True`` (2k features, as :meth:`LogDistortion.transform`);
* a kernel maps ``g`` to ln δ1 (and, for the ensemble, its predictive variance): :class:`MLPKernel` (FFNN),
  :class:`EnsembleKernel` (deep ensemble; members stacked for one batched matmul per layer) and :class:`GRUKernel`
  (recurrent; ``step`` carries the hidden state). ``row`` is the single-row NumPy path (float64); ``batch`` runs the
  model's own torch modules over cache-sized chunks in inference mode (float32, as trained).

δ1 = π1(source)/π1(target) as in :mod:`scaling.dimensions.factors`; the kernels only compute ln δ1.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from scaling.dimensions.factors import LogDistortion
from scaling.dimensions.groups import PiGroup
from scaling.models import DeepEnsemble, DeltaModel, GRUModel
from scaling.models.ffnn import FFNN
from zoo.serving.networks import NUMPY_ACTIVATIONS, SingleNet, TorchMLP, linears
from zoo.serving.recurrent import GRUKernel

#: Rows per chunk of the batch path (keeps activations in cache).
CHUNK = 8192


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
    """The model inputs of :meth:`scaling.dimensions.factors.LogDistortion.transform` for fixed source group values.

    With ``h(π) = s·asinh(π/2ε)`` (dimensionless, like the groups π) the features of a target are
    ``g = h(π^s) − h(π^t)`` (k of them), followed by ``h(π^s)`` itself when the model was fitted with
    ``include_source=True`` (2k). ``h_source`` holds ``h(π^s)`` of one source row (k,) or of n paired rows (n, k).
    """

    scale: np.ndarray  # 1/(2ε), (k,)
    sign: np.ndarray  # s_n, (k,)
    h_source: np.ndarray  # s·asinh(π^s/2ε), (k,) or (n, k)
    include_source: bool = False  # append h_source to g (the transform's include_source)

    @classmethod
    def build(cls, transform: LogDistortion, pi_source: np.ndarray) -> Features:
        """The features of a fitted ``transform`` (its ε, s and ``include_source``) for source group values
        ``pi_source`` (k,) or (n, k)."""
        if transform.eps is None or transform.sign is None:
            raise ValueError("the model's feature transform is not fitted")
        scale = 0.5 / np.asarray(transform.eps, dtype=float)
        unbound = cls(scale, np.asarray(transform.sign, dtype=float), np.empty(0), bool(transform.include_source))
        return unbound.with_source(pi_source)

    def h(self, pi: np.ndarray) -> np.ndarray:
        """``s·asinh(π/2ε)`` of group values ``pi`` (k,) or (n, k)."""
        return self.sign * np.arcsinh(pi * self.scale)

    def __call__(self, pi_target: np.ndarray) -> np.ndarray:
        """Features of target group values (k,) or (n, k): shape (k,)/(n, k), or (2k,)/(n, 2k) with the source."""
        g = self.h_source - self.sign * np.arcsinh(pi_target * self.scale)
        if not self.include_source:
            return g
        return np.concatenate([g, np.broadcast_to(self.h_source, g.shape)], axis=-1)

    @property
    def n_features(self) -> int:
        """Number of model inputs: k, or 2k with the source's own features."""
        k = len(self.scale)
        return 2 * k if self.include_source else k

    def rows(self, start: int, stop: int) -> Features:
        """The features of paired sources ``start:stop`` (``h_source`` of shape (n, k))."""
        return Features(self.scale, self.sign, self.h_source[start:stop], self.include_source)

    def with_source(self, pi_source: np.ndarray) -> Features:
        """The same transform for other source group values ``pi_source`` (k,) or (n, k)."""
        return Features(self.scale, self.sign, self.h(np.asarray(pi_source, dtype=float)), self.include_source)


class MLPKernel(SingleNet):
    """An :class:`FFNN`: standardise g, MLP, un-standardise → ln δ1."""

    def __init__(self, model: FFNN) -> None:
        super().__init__(model)
        self.layers = linears(self.net)
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


@dataclass(frozen=True)
class BoundMLPRow:
    """The one-row path of an :class:`MLPKernel` with one bound source, folded into its first layer.

    With the source fixed, the features are ``g = h(π^s) − s·u`` (and ``h(π^s)`` itself for an ``include_source``
    model) with ``u = asinh(π^t/2ε)``, and the standardisation is affine, so the first layer's pre-activation is
    ``c + u @ A``: ``c`` holds the source's part (its constant features included) and the standardisation, ``A``
    the sign and the scale of each target group. The training-range check on ``g`` becomes bounds on ``u``
    (``asinh`` is increasing, ``s = ±1``). Same arithmetic as ``features`` + :meth:`MLPKernel.row` in float64 up
    to rounding (tests/zoo/test_serving.py), at about half the per-call cost: a row costs its NumPy calls.
    """

    scale: np.ndarray  # 1/(2ε) per target group, (k,)
    const: np.ndarray  # first-layer pre-activation of u = 0, (width,)
    weight: np.ndarray  # (k, width)
    hidden: tuple[tuple[np.ndarray, np.ndarray], ...]  # the remaining layers (w, b)
    act: Callable[[np.ndarray], np.ndarray]  # the NumPy activation
    y_mean: float
    y_std: float
    u_lo: np.ndarray  # u inside [u_lo, u_hi] <=> the target's features inside the training range
    u_hi: np.ndarray
    source_outside: bool  # the bound source's own features (include_source) already outside the range

    @classmethod
    def build(cls, kernel: MLPKernel, features: Features, g_lo: np.ndarray, g_hi: np.ndarray) -> BoundMLPRow | None:
        """The folded row path, or ``None`` where it does not apply (several sources, no NumPy activation)."""
        if kernel.act is None or features.h_source.ndim != 1:
            return None
        k = len(features.scale)
        h_s, sign = features.h_source, features.sign
        (w0, b0), *rest = kernel.layers
        xm, xs = kernel.x_mean, kernel.x_std
        const = b0 + ((h_s - xm[:k]) / xs[:k]) @ w0[:k]
        source_outside = False
        if features.include_source:
            const = const + ((h_s - xm[k:]) / xs[k:]) @ w0[k:]
            source_outside = bool(((h_s < g_lo[k:]) | (h_s > g_hi[k:])).any())
        weight = -(sign / xs[:k])[:, None] * w0[:k]
        # g = h_s − s·u in [lo, hi]  <=>  s·u in [h_s − hi, h_s − lo]
        a, b = h_s - g_hi[:k], h_s - g_lo[:k]
        u_lo, u_hi = np.where(sign > 0, a, -b), np.where(sign > 0, b, -a)
        return cls(features.scale, const, weight, tuple(rest), kernel.act, kernel.y_mean, kernel.y_std, u_lo, u_hi,
                   source_outside)

    def __call__(self, pi_target: np.ndarray) -> tuple[float, bool]:
        """(ln δ1, outside the training range) of one target's group values ``pi_target`` (k,)."""
        u = np.arcsinh(pi_target * self.scale)
        h = self.const + u @ self.weight
        for w, b in self.hidden:  # an activation after every layer but the last
            h = self.act(h) @ w + b
        outside = self.source_outside or bool((u < self.u_lo).any() or (u > self.u_hi).any())
        return self.y_mean + self.y_std * float(h[0]), outside


class EnsembleKernel:
    """A :class:`DeepEnsemble`: K Gaussian MLPs, each with its own standardisers; mixture mean and variance."""

    def __init__(self, model: DeepEnsemble) -> None:
        members = model.members_
        self.nets = [m.net_.eval() for m in members]
        self.x_mean = np.stack([m.x_scale_.mean for m in members]).astype(float)[:, None, :]
        self.x_std = np.stack([m.x_scale_.std for m in members]).astype(float)[:, None, :]
        self.y_mean = np.array([float(m.y_scale_.mean[0]) for m in members])
        self.y_std = np.array([float(m.y_scale_.std[0]) for m in members])
        per_member = [linears(n) for n in self.nets]
        self.layers = [(np.stack([p[i][0] for p in per_member]), np.stack([p[i][1] for p in per_member])[:, None, :])
                       for i in range(len(per_member[0]))]
        # row path: the members' input standardisation folded into their first layer (float64, exact enough)
        w0, b0 = self.layers[0]
        self._row_layers = [(w0 / self.x_std.transpose(0, 2, 1), b0 - np.matmul(self.x_mean / self.x_std, w0)),
                            *self.layers[1:]]
        self._y = list(zip(self.y_mean.tolist(), self.y_std.tolist(), strict=True))
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
        h = g[None, None, :]
        last = len(self._row_layers) - 1
        for i, (w, b) in enumerate(self._row_layers):
            h = np.matmul(h, w) + b
            if i < last:
                h = self.act(h)
        # the mixture of :meth:`_mixture` on K plain floats: NumPy's per-call cost dominates at this size
        mus, second = [], 0.0
        for (out_mu, out_log_var), (y_mean, y_std) in zip(h.reshape(-1, 2).tolist(), self._y, strict=True):
            mu = y_mean + y_std * out_mu
            mus.append(mu)
            second += math.exp(min(max(out_log_var, -12.0), 8.0)) * y_std * y_std + mu * mu
        mean = sum(mus) / len(mus)
        return mean, max(second / len(mus) - mean * mean, 0.0)

    def batch(self, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mean, variance) of ln δ1 for feature rows ``g`` (n, k), one chunk at a time."""
        return self._mixture(np.stack([mlp(g) for mlp in self.torch_mlps]))


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


__all__ = ["CHUNK", "BoundMLPRow", "EnsembleKernel", "Features", "GRUKernel", "GroupPlan", "Kernel", "MLPKernel",
           "kernel_for", "normal_quantile"]
