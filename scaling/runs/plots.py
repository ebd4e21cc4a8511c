"""Figures of the paper; every function saves a PNG (optional) and returns the :class:`~matplotlib.figure.Figure`.

Figures are built with matplotlib's object API and rendered by the Agg canvas, without pyplot: no global backend
switch, no window, nothing to close.

* :func:`plot_predicted_vs_actual`: predicted against actual δ1 with R² and the y = x line (Figs. 6, 7);
* :func:`plot_grid_heatmap`: mean R² over units per layer × dropout (Fig. 8);
* :func:`plot_grid_landscape`: units × dropout × R², colour = learning rate, marker = hidden layers (Fig. 9);
* :func:`plot_r2_vs_units`: mean R² against units per layer (Fig. 10);
* :func:`plot_error_vs_load`: percentage error against the carried load per model, dashed means (Fig. 12);
  :func:`plot_mini_validation` draws it for a :class:`~scaling.evaluation.miniature.MiniValidation`.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure

from scaling.evaluation.miniature import MiniValidation
from scaling.models.base import r2_score

PathLike = str | Path | None


def _figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    return fig


def _finish(fig: Figure, path: PathLike) -> Figure:
    fig.tight_layout()
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=150)
    return fig


def plot_predicted_vs_actual(actual: np.ndarray, predicted: np.ndarray, path: PathLike = None, *,
                             title: str = "Prediction factor δ1", label: str = "δ1") -> Figure:
    """Scatter of predicted against actual δ1 = π1(source)/π1(target), the y = x line and R² in the title."""
    a, p = np.asarray(actual, dtype=float).ravel(), np.asarray(predicted, dtype=float).ravel()
    fig = _figure(5, 5)
    ax = fig.subplots()
    ax.scatter(a, p, s=6, alpha=0.5, label="pairs")
    lo, hi = float(np.nanmin([a.min(), p.min()])), float(np.nanmax([a.max(), p.max()]))
    ax.plot([lo, hi], [lo, hi], "k--", lw=1, label="y = x")
    ax.set(xlabel=f"actual {label}", ylabel=f"predicted {label}", title=f"{title}  (R² = {r2_score(a, p):.3f})")
    ax.legend(loc="upper left")
    return _finish(fig, path)


def plot_grid_heatmap(results: pd.DataFrame, path: PathLike = None, *, rows: str = "units",
                      cols: str = "dropout", value: str = "r2") -> Figure:
    """Heat map of the mean ``value`` (held-out R²) over ``rows`` × ``cols``, averaged over the other parameters."""
    table = results.pivot_table(index=rows, columns=cols, values=value, aggfunc="mean").sort_index()
    fig = _figure(1.2 * table.shape[1] + 3, 0.6 * table.shape[0] + 2)
    ax = fig.subplots()
    im = ax.imshow(table.to_numpy(dtype=float), cmap="viridis", aspect="auto", origin="lower")
    ax.set_xticks(range(table.shape[1]), [f"{c:g}" for c in table.columns])
    ax.set_yticks(range(table.shape[0]), [f"{r:g}" for r in table.index])
    values = table.to_numpy(dtype=float)
    for (i, j), v in np.ndenumerate(values):
        ax.text(j, i, f"{v:.3f}", ha="center", va="center", color="w" if v < np.nanmean(values) else "k", fontsize=8)
    ax.set(xlabel=cols, ylabel=rows, title=f"mean {value}")
    fig.colorbar(im, ax=ax, label=f"mean {value}")
    return _finish(fig, path)


def plot_grid_landscape(results: pd.DataFrame, path: PathLike = None, *, value: str = "r2") -> Figure:
    """3-D scatter units × dropout × R²; colour = learning rate (log), marker = number of hidden layers."""
    fig = _figure(7, 5)
    ax = fig.add_subplot(projection="3d")
    markers = "osD^v<>p*h"
    norm = LogNorm(vmin=results["lr"].min(), vmax=results["lr"].max())
    for i, (layers, sub) in enumerate(results.groupby("hidden_layers")):
        sc = ax.scatter(sub["units"], sub["dropout"], sub[value], c=sub["lr"], cmap="plasma", norm=norm,
                        marker=markers[i % len(markers)], label=f"{layers} layers")
    ax.set(xlabel="units", ylabel="dropout", zlabel=value)
    fig.colorbar(sc, ax=ax, label="learning rate", shrink=0.7)
    for handle in ax.legend(loc="upper left").legend_handles:  # marker shape only; colour is the learning rate
        handle.set_color("0.4")
    return _finish(fig, path)


def plot_r2_vs_units(results: pd.DataFrame, path: PathLike = None, *, value: str = "r2") -> Figure:
    """Mean (± std) held-out R² against units per layer, averaged over the other hyper-parameters."""
    stats = results.groupby("units")[value].agg(["mean", "std"]).sort_index()
    fig = _figure(5, 4)
    ax = fig.subplots()
    ax.errorbar(stats.index, stats["mean"], yerr=stats["std"].fillna(0.0), marker="o", capsize=3)
    ax.set(xlabel="units per hidden layer", ylabel=f"mean {value}", title=f"{value} against network width")
    ax.set_xscale("log", base=2)
    return _finish(fig, path)


def plot_error_vs_load(load: np.ndarray, errors: Mapping[str, np.ndarray], path: PathLike = None, *,
                       load_label: str = "load (kg)") -> Figure:
    """Percentage error of each model against the carried load; dashed lines mark each model's mean error."""
    x = np.asarray(load, dtype=float)
    order = np.argsort(x)
    fig = _figure(6, 4)
    ax = fig.subplots()
    for name, err in errors.items():
        e = np.asarray(err, dtype=float)
        line = ax.plot(x[order], e[order], marker="o", ms=3, label=name)[0]
        ax.axhline(float(np.mean(e)), ls="--", color=line.get_color(), lw=1,
                   label=f"{name} mean {np.mean(e):.2f} %")
    ax.set(xlabel=load_label, ylabel="error (%)", title="scaling error against load")
    ax.legend(fontsize=8)
    return _finish(fig, path)


def plot_mini_validation(mini: MiniValidation, path: PathLike = None) -> Figure:
    """Fig. 12 of a miniature validation: absolute percentage error against load per model, dashed means."""
    return plot_error_vs_load(mini.loads_kg, mini.abs_pct_errors(), path)
