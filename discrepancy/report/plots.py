"""Plots of a diagnosis (matplotlib, headless): real, twin and corrected traces of the most affected signals, with
the located windows shaded, and a map of effect sizes over signals × windows."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from discrepancy.pipeline import Diagnosis
from scaletwin_envs.signal_units import SIGNAL_UNITS


def top_signals(d: Diagnosis, n: int = 6) -> list[str]:
    """The signals with the largest residual before the correction."""
    order = sorted(d.comparison.before, key=lambda s: -d.comparison.before[s])
    return [s for s in order if np.isfinite(d.comparison.before[s])][:n]


def _traces(d: Diagnosis, stem: Path) -> Path:
    names = top_signals(d, 6)
    ep = d.held_out[0] if d.held_out else d.train
    runs = d.traces[ep.name]
    fig, axes = plt.subplots(len(names), 1, figsize=(9, 1.8 * len(names) + 0.6), sharex=True, squeeze=False)
    for ax, s in zip(axes[:, 0], names, strict=True):
        ax.plot(ep.time, ep.signals[s], color="k", lw=1.0, label="real")
        ax.plot(ep.time, runs["twin"].signals[s], color="tab:blue", lw=1.0, label="twin")
        ax.plot(ep.time, runs["corrected"].signals[s], color="tab:orange", lw=1.0, ls="--", label="corrected")
        if ep is d.train:
            for loc in d.located:
                if loc.signal == s:
                    ax.axvspan(loc.t_start, loc.t_end, color="tab:red", alpha=0.12, lw=0)
        ax.set_ylabel(f"{s} [{SIGNAL_UNITS.get(s, '')}]", fontsize=8)
    axes[0, 0].legend(loc="upper right", fontsize=8, ncol=3)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(f"{ep.name}: real vs twin vs corrected" + (" (held out)" if ep is not d.train else ""), fontsize=10)
    fig.tight_layout()
    path = stem.parent / f"{stem.name}_traces.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _effect_map(d: Diagnosis, stem: Path) -> Path | None:
    res = d.locate_result
    if res is None:
        return None
    fig, ax = plt.subplots(figsize=(10, 0.22 * len(res.names) + 1.5))
    image = ax.imshow(res.effect.T, aspect="auto", cmap="magma", interpolation="nearest")
    ax.set_yticks(range(len(res.names)), res.names, fontsize=7)
    ax.set_xticks(range(len(res.wins)), [w.phase[:4] for w in res.wins], rotation=90, fontsize=6)
    hits = np.argwhere(res.q <= 0.01)
    ax.scatter(hits[:, 0], hits[:, 1], s=6, c="cyan", marker="s", label="located")
    fig.colorbar(image, ax=ax, label="effect size (RMS excess over null)")
    ax.set_title("effect size per signal × window (located in cyan)", fontsize=10)
    fig.tight_layout()
    path = stem.parent / f"{stem.name}_effect_map.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def save_plots(d: Diagnosis, stem: Path) -> list[Path]:
    """Write the plots as ``<stem>_*.png``; returns their paths."""
    stem.parent.mkdir(parents=True, exist_ok=True)
    return [p for p in (_traces(d, stem), _effect_map(d, stem)) if p is not None]
