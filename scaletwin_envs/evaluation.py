"""KPI harness: compare dig policies over seeded episodes at several machine sizes and soils.

:func:`evaluate_policies` runs every (policy, scale, soil, seed) episode through the executor seam
(:mod:`scaletwin_envs.parallel`) and returns one row per episode; :func:`summarize` aggregates them per
policy, scale and soil. :func:`write_markdown`, :func:`write_csv` and :func:`plot_kpis` write the report.
Every policy meets the same seeds (common random numbers), so differences are due to the policies.

Policies are objects (a callable obs → action, or anything with Stable-Baselines3's ``predict``); they
travel to worker processes by pickling, so they must be picklable. Learned policies come from the zoo
(``zoo.load``), which this package never imports.
"""

from __future__ import annotations

import datetime as _dt
import platform
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd

import scaletwin_envs
from scaletwin_envs.host import host_line
from scaletwin_envs.parallel import Executor, make_executor
from scaletwin_envs.rollout import run_episode
from scaletwin_envs.specs.loader import LoaderSpec

PRESET_SCALES: tuple[str, ...] = ("mini", "er12", "wa475")
DEFAULT_SCALES: tuple[float | str, ...] = (*PRESET_SCALES, 0.3, 1.5)
DEFAULT_SOILS: tuple[str, ...] = ("gravel", "clay_loam")
#: Summary columns: (column, heading with unit, format).
KPI_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("fill_factor", "fill factor", ".3f"), ("loaded_mass", "loaded mass [kg]", ".4g"),
    ("cycle_time", "cycle time [s]", ".3g"), ("cycle_time_froude", "cycle time [√(L/g)]", ".3g"),
    ("hydraulic_work", "hydraulic work [J]", ".4g"), ("specific_energy", "specific energy [J/kg]", ".3g"),
    ("spilled_mass", "spilled mass [kg]", ".3g"), ("success_rate", "success rate", ".0%"),
    ("sim_errors", "sim errors", "d"),
)
_MEANS = ("fill_factor", "loaded_mass", "cycle_time", "cycle_time_froude", "hydraulic_work", "specific_energy",
          "spilled_mass")


@dataclass(frozen=True)
class EpisodeTask:
    """One evaluation episode (picklable)."""

    policy_name: str
    policy: Any
    scale: float | str | LoaderSpec
    soil: str
    seed: int
    law: str = "product_line"
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)


def run_task(task: EpisodeTask) -> dict[str, Any]:
    """Run one episode; a row of KPIs (specific energy is NaN for an empty bucket). The row's ``scale`` is the preset
    or length ratio as text, or the :class:`LoaderSpec`'s name."""
    env = gym.make(scaletwin_envs.ENV_ID, scale=task.scale, soil=task.soil, law=task.law, **task.env_kwargs)
    policy = task.policy
    if hasattr(policy, "reseed"):
        policy.reseed(task.seed)
    try:
        kpis = run_episode(env, policy, seed=task.seed).kpis.to_dict()
        ratio = float(env.unwrapped.loader.scale)
    finally:
        env.close()
    if not np.isfinite(kpis["specific_energy"]):
        kpis["specific_energy"] = float("nan")
    label = task.scale.name if isinstance(task.scale, LoaderSpec) else str(task.scale)
    return {"policy": task.policy_name, "scale": label, "length_ratio": ratio, "soil": task.soil,
            "seed": task.seed, **kpis}


def evaluate_policies(policies: Mapping[str, Any], scales: Sequence[float | str | LoaderSpec] = DEFAULT_SCALES,
                      soils: Sequence[str] = DEFAULT_SOILS, episodes: int = 5, seed: int = 0, *,
                      law: str = "product_line", env_kwargs: Mapping[str, Any] | None = None,
                      executor: Executor | str | int | None = None) -> pd.DataFrame:
    """Run ``episodes`` seeded episodes (seeds ``seed .. seed+episodes-1``) per policy, scale and soil.

    Args:
        policies: name → policy object.  scales: presets, length ratios or :class:`LoaderSpec` machines (e.g.
            :meth:`~scaletwin_envs.design_space.DesignSpace.sample`'s ``.spec``, rows labelled by its name).
        soils: soil names.
        env_kwargs: further env arguments (default: no second-route force check, which KPIs do not need).
        executor: the executor seam's spec (``None``: all local cores, ``"serial"``, an int, an Executor).

    Returns:
        One row per episode: policy, scale, length_ratio, soil, seed and the :class:`EpisodeKPIs` fields, in
        a stable order (policy, scale, soil, seed as given).
    """
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    if not policies:
        raise ValueError("give at least one policy")
    kwargs = {"two_route_check": False, **(env_kwargs or {})}
    tasks = [EpisodeTask(name, pol, scale, soil, seed + i, law, kwargs)
             for name, pol in policies.items() for scale in scales for soil in soils for i in range(episodes)]
    rows: list[dict[str, Any] | None] = [None] * len(tasks)
    for i, row in make_executor(executor).map_unordered(run_task, tasks):
        rows[i] = row
    return pd.DataFrame(rows)


def summarize(episodes: pd.DataFrame) -> pd.DataFrame:
    """Mean KPIs per policy, scale and soil, with success rate, sim-error count and episode count.

    Rows are ordered scale, soil, policy (each in the order first met), so policies sit side by side.
    """
    keys = ["scale", "soil", "policy"]
    grouped = episodes.groupby(keys, sort=False)
    out = grouped[["length_ratio", *_MEANS]].mean()
    out["success_rate"] = grouped["success"].mean()
    out["sim_errors"] = grouped["sim_error"].apply(lambda s: int(s.notna().sum()))
    out["episodes"] = grouped.size()
    out = out.reset_index()
    rank = {k: {v: i for i, v in enumerate(dict.fromkeys(episodes[k]))} for k in keys}
    order = sorted(range(len(out)), key=lambda i: tuple(rank[k][out.at[i, k]] for k in keys))
    return out.iloc[order].reset_index(drop=True)[["policy", "scale", "soil", *out.columns[3:]]]


def _fmt(value: Any, spec: str) -> str:
    if isinstance(value, float) and not np.isfinite(value):
        return "–"
    return format(int(value) if spec == "d" else value, spec)


def summary_rows(summary: pd.DataFrame) -> tuple[list[str], list[list[str]]]:
    """Headings and formatted cells of the summary table (for Markdown and the terminal)."""
    heads = ["policy", "scale", "soil", *(h for _, h, _ in KPI_COLUMNS), "episodes"]
    rows = [[str(r["policy"]), str(r["scale"]), str(r["soil"]),
             *(_fmt(r[c], spec) for c, _, spec in KPI_COLUMNS), str(int(r["episodes"]))]
            for _, r in summary.iterrows()]
    return heads, rows


def machine_info() -> str:
    """One line: date, CPU, core count, Python and key package versions."""
    import mujoco
    import torch

    return (f"{_dt.date.today().isoformat()}, {host_line()}, Python {platform.python_version()}, "
            f"mujoco {mujoco.__version__}, torch {torch.__version__}")


def write_markdown(summary: pd.DataFrame, path: str | Path, title: str = "Policy KPIs", notes: str = "") -> Path:
    """The summary as a Markdown table with the machine and date."""
    heads, rows = summary_rows(summary)
    lines = [f"# {title}", "", f"Machine: {machine_info()}.", ""]
    if notes:
        lines += [notes.strip(), ""]
    lines += ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def write_csv(frame: pd.DataFrame, path: str | Path) -> Path:
    """A summary or per-episode frame as CSV."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frame.to_csv(path, index=False)
    return path


def plot_kpis(summary: pd.DataFrame, path: str | Path,
              kpis: Sequence[str] = ("fill_factor", "cycle_time_froude", "specific_energy"),
              target_fill: float = 0.85) -> Path:
    """Mean KPI vs length ratio (log axis), one row of panels per soil, one line per policy; the fill target
    dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    soils = list(dict.fromkeys(summary["soil"]))
    heads = {c: h for c, h, _ in KPI_COLUMNS}
    fig, axes = plt.subplots(len(soils), len(kpis), figsize=(4.2 * len(kpis), 3.2 * len(soils)), squeeze=False)
    for r, soil in enumerate(soils):
        for c, kpi in enumerate(kpis):
            ax = axes[r][c]
            for name, part in summary[summary["soil"] == soil].groupby("policy", sort=False):
                part = part.sort_values("length_ratio")
                ax.plot(part["length_ratio"], part[kpi], marker="o", label=str(name))
            ax.set_xscale("log")
            ticks = sorted(set(summary["length_ratio"]))
            ax.set_xticks(ticks, [f"{t:.3g}" for t in ticks])
            ax.xaxis.set_minor_formatter(NullFormatter())
            if kpi == "specific_energy":
                ax.set_yscale("log")
            if kpi == "fill_factor":
                ax.axhline(target_fill, color="grey", linestyle="--", linewidth=0.8)
            ax.set_xlabel("length ratio λ (vs ER12)")
            ax.set_title(f"{heads.get(kpi, kpi)} — {soil}", fontsize=9)
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
