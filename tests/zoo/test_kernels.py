"""The serving kernels against the scaling package's own torch networks: two routes to the same ln δ1."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from scaling.models import GRUModel
from scaling.models._torch import Standardiser
from zoo.serving import recurrent
from zoo.serving.recurrent import GRUKernel


@pytest.fixture(scope="module")
def two_layer_gru() -> GRUModel:
    """An untrained two-layer GRU with non-trivial standardisers (the kernel must not assume one layer)."""
    rng = np.random.default_rng(3)
    model = GRUModel(hidden_size=12, num_layers=2, seed=5)
    torch.manual_seed(5)
    model.net_ = model._build(5).eval()
    model.x_scale_ = Standardiser(rng.normal(size=5), rng.uniform(0.5, 2.0, size=5))
    model.y_scale_ = Standardiser(np.array([0.3]), np.array([1.7]))
    return model


def _torch_route(model: GRUModel, g: np.ndarray) -> np.ndarray:
    """ln δ1 of one sequence ``g`` (T, k) through ``nn.GRU`` itself."""
    assert model.x_scale_ is not None and model.y_scale_ is not None and model.net_ is not None
    z = torch.from_numpy(((g - model.x_scale_.mean) / model.x_scale_.std).astype(np.float32))[None]
    with torch.inference_mode():
        out = model.net_(z)[0].double().numpy()
    return model.y_scale_.mean[0] + model.y_scale_.std[0] * out


@pytest.mark.parametrize("threads", [1, 3])
def test_gru_sequences_match_nn_gru_and_the_step_path(two_layer_gru: GRUModel, threads: int,
                                                      monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setattr(recurrent, "BLOCK_ROWS", 200)  # force batches to split across blocks and calls
    kernel = GRUKernel(two_layer_gru)
    rng = np.random.default_rng(0)
    lengths = [1, 130, 130, 130, 7, 64, 65]  # across TIME_BLOCK boundaries; one group of equal lengths
    g = rng.normal(size=(sum(lengths), 5))
    seqs = np.split(np.arange(len(g)), np.cumsum(lengths)[:-1])
    seqs = [seqs[i] for i in (3, 0, 6, 1, 5, 2, 4)]  # not in row order
    got = kernel.sequences(g, seqs, threads=threads)
    for idx in seqs:
        np.testing.assert_allclose(got[idx], _torch_route(two_layer_gru, g[idx]), rtol=1e-5, atol=1e-6)
    state, stepped = kernel.initial_state(), []
    for row in g[seqs[0]]:
        value, state = kernel.step(row, state)
        stepped.append(value)
    np.testing.assert_allclose(got[seqs[0]], stepped, rtol=1e-5, atol=1e-6)
