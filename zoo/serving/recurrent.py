"""The GRU kernel: one step at a time in NumPy (live streams) or many sequences at once in torch (batches)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from scaling.models import GRUModel
from zoo.serving.networks import SingleNet, linears
from zoo.serving.parallel import map_ordered

#: Steps whose input projections are computed in one matmul.
TIME_BLOCK = 64
#: At most this many (sequence, step) rows per block: bounds memory for batches of many sequences.
BLOCK_ROWS = 65536

class GRUKernel(SingleNet):
    """A :class:`GRUModel`: one step at a time (``step``, NumPy, hidden state carried) or whole sequences."""

    def __init__(self, model: GRUModel) -> None:
        super().__init__(model)
        gru = self.net.gru
        self.hidden, self.num_layers = gru.hidden_size, gru.num_layers
        self.cells = [tuple(getattr(gru, f"{n}_l{i}").detach().double().numpy().copy()
                            for n in ("weight_ih", "weight_hh", "bias_ih", "bias_hh")) for i in range(self.num_layers)]
        w, b = linears(self.net.head)[0]
        self.head_w, self.head_b = w[:, 0], float(b[0])
        self.torch_cells = [(getattr(gru, f"weight_ih_l{i}").detach().t(),
                             getattr(gru, f"weight_hh_l{i}").detach().t().contiguous(),
                             getattr(gru, f"bias_ih_l{i}").detach(), getattr(gru, f"bias_hh_l{i}").detach())
                            for i in range(self.num_layers)]
        self.torch_head = (self.net.head.weight.detach().t(), self.net.head.bias.detach())

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

        Sequences of equal length run together (:meth:`forward`) in batches of at most :data:`BLOCK_ROWS` rows per
        block of steps; with ``threads`` > 1 the batches run at once (the same results up to float32 rounding).
        """
        z = ((g - self.x_mean) / self.x_std).astype(np.float32)
        out = np.empty(len(g))
        by_length: dict[int, list[np.ndarray]] = {}
        for s in seqs:
            by_length.setdefault(len(s), []).append(np.asarray(s))
        parts = []
        for length, group in by_length.items():
            most = max(1, BLOCK_ROWS // min(length, TIME_BLOCK))
            parts += np.array_split(np.stack(group), max(min(threads, len(group)), -(-len(group) // most)))

        def run(idx: np.ndarray) -> None:
            out[idx] = self.forward(z[idx])

        map_ordered(run, parts, threads)
        return self.y_mean + self.y_std * out

    def forward(self, z: np.ndarray) -> np.ndarray:
        """Network output (B, T) of standardised sequences ``z`` (B, T, k) float32 from a zero state.

        ``torch.nn.GRU``'s equations (gates r, z, n) written out step by step: the input projections of a block of
        :data:`TIME_BLOCK` steps are one matmul, each step one small matmul and four fused element-wise ops, about
        1.4 times the throughput of ``nn.GRU`` on one CPU thread for these sizes (``benchmarks/serving.py``).
        """
        n_seq, n_steps, _ = z.shape
        hdim = self.hidden
        x_all = torch.from_numpy(np.ascontiguousarray(z.transpose(1, 0, 2)))  # time-major (T, B, k)
        state = [torch.zeros(n_seq, hdim) for _ in self.torch_cells]
        out = torch.empty(n_steps, n_seq)
        w_head, b_head = self.torch_head
        with torch.inference_mode():
            for start in range(0, n_steps, TIME_BLOCK):
                x = x_all[start:start + TIME_BLOCK]
                steps = len(x)
                for layer, (w_ih, w_hh, b_ih, b_hh) in enumerate(self.torch_cells):
                    gi = torch.addmm(b_ih, x.reshape(steps * n_seq, -1), w_ih).view(steps, n_seq, 3 * hdim)
                    ys, h = torch.empty(steps, n_seq, hdim), state[layer]
                    for s in range(steps):
                        gh = torch.addmm(b_hh, h, w_hh)
                        rz = torch.sigmoid_(gi[s, :, :2 * hdim] + gh[:, :2 * hdim])
                        n = torch.tanh_(torch.addcmul(gi[s, :, 2 * hdim:], rz[:, :hdim], gh[:, 2 * hdim:]))
                        h = ys[s] = torch.addcmul(n, rz[:, hdim:], h - n)
                    state[layer], x = h, ys
                out[start:start + steps] = torch.addmm(b_head, x.reshape(steps * n_seq, hdim), w_head).view(steps,
                                                                                                          n_seq)
        return out.t().double().numpy()


__all__ = ["BLOCK_ROWS", "TIME_BLOCK", "GRUKernel"]
