"""The KPI harness (function and CLI) on tiny runs."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest

import scaletwin_envs
import zoo
from scaletwin.cli import main
from scaletwin_envs.evaluation import KPI_COLUMNS, evaluate_policies, plot_kpis, summarize, write_csv, write_markdown
from scaletwin_envs.physics.bucket import heaped_capacity
from scaletwin_envs.policies import RandomPolicy, ScriptedDigPolicy
from scaletwin_envs.rollout import run_episode
from scaletwin_envs.specs import make_loader, make_soil

#: KPIs read off the episode (the others follow from them, see ``_check_derived``).
EPISODE_KPIS = ("fill_factor", "loaded_mass", "cycle_time", "hydraulic_work", "spilled_mass", "steps", "success")


@pytest.fixture(scope="module")
def episodes() -> pd.DataFrame:
    return evaluate_policies({"scripted": ScriptedDigPolicy(), "random": RandomPolicy()}, scales=["mini", 0.3],
                             soils=["gravel"], episodes=2, seed=0, executor="serial")


def test_one_row_per_episode(episodes: pd.DataFrame):
    assert len(episodes) == 2 * 2 * 2
    assert list(episodes["seed"][:2]) == [0, 1]
    for col in ("policy", "scale", "length_ratio", "soil", "fill_factor", "loaded_mass", "cycle_time",
                "cycle_time_froude", "hydraulic_work", "specific_energy", "spilled_mass", "success", "sim_error"):
        assert col in episodes.columns, col
    scripted = episodes[episodes["policy"] == "scripted"]
    assert (scripted["fill_factor"] > 0.7).all() and scripted["sim_error"].isna().all()


def test_summary_aggregates(episodes: pd.DataFrame):
    summary = summarize(episodes)
    assert len(summary) == 4
    for col, _, _ in KPI_COLUMNS:
        assert col in summary.columns
    row = summary[(summary["policy"] == "scripted") & (summary["scale"] == "mini")].iloc[0]
    part = episodes[(episodes["policy"] == "scripted") & (episodes["scale"] == "mini")]
    assert row["fill_factor"] == pytest.approx(part["fill_factor"].mean())
    assert row["episodes"] == 2 and row["sim_errors"] == 0


def test_same_seeds_same_results():
    a = evaluate_policies({"s": ScriptedDigPolicy()}, ["mini"], ["gravel"], 1, seed=4, executor="serial")
    b = evaluate_policies({"s": ScriptedDigPolicy()}, ["mini"], ["gravel"], 1, seed=4, executor="serial")
    np.testing.assert_array_equal(a["fill_factor"], b["fill_factor"])


def test_writers(episodes: pd.DataFrame, tmp_path: Path):
    summary = summarize(episodes)
    md = write_markdown(summary, tmp_path / "k.md").read_text()
    assert "| policy | scale | soil | fill factor" in md and "Machine:" in md and "scripted" in md
    assert len(pd.read_csv(write_csv(summary, tmp_path / "k.csv"))) == 4
    assert plot_kpis(summary, tmp_path / "k.png").stat().st_size > 1000


def test_rejects_empty_runs():
    with pytest.raises(ValueError):
        evaluate_policies({}, ["mini"], ["gravel"], 1)
    with pytest.raises(ValueError):
        evaluate_policies({"s": ScriptedDigPolicy()}, ["mini"], ["gravel"], 0)


def _check_derived(row: pd.Series, scale: str, soil: str) -> None:
    """KPIs that follow from others by their definitions: Froude time √(L/g), J/kg, fill = mass / (ρ V_heaped)."""
    spec, density = make_loader(scale), make_soil(soil).density
    assert row["cycle_time_froude"] == pytest.approx(row["cycle_time"] / math.sqrt(spec.characteristic_length / 9.81),
                                                     rel=1e-9)
    if row["loaded_mass"] > 0:
        assert row["specific_energy"] == pytest.approx(row["hydraulic_work"] / row["loaded_mass"], rel=1e-9)
    else:  # an empty bucket has no energy per kilogram
        assert math.isnan(row["specific_energy"])
    assert row["loaded_mass"] == pytest.approx(row["fill_factor"] * heaped_capacity(spec.geometry) * density, rel=1e-9)
    assert row["length_ratio"] == pytest.approx(spec.scale, rel=1e-12)


def test_cli_writes_table_files(tmp_path: Path, capsys):
    """The CLI's per-episode table is each policy's seeded episode rolled out directly (the zoo checkpoint as
    'learned'); the summary and the Markdown table hold the same numbers."""
    rc = main(["evaluate-policy", "--policies", "learned,scripted,random", "--scales", "mini", "--soils", "gravel",
               "--episodes", "1", "--workers", "serial", "--out", str(tmp_path)])
    assert rc == 0
    out = capsys.readouterr().out
    assert "learned" in out and "scripted" in out and "random" in out
    for name in ("policy_kpis.md", "policy_kpis.csv", "policy_kpis_episodes.csv", "policy_kpis.png"):
        assert (tmp_path / name).is_file(), name
    episodes = pd.read_csv(tmp_path / "policy_kpis_episodes.csv")
    summary = pd.read_csv(tmp_path / "policy_kpis.csv")
    markdown = (tmp_path / "policy_kpis.md").read_text()
    policies: dict[str, Any] = {"learned": zoo.load("bucketfill-ppo"), "scripted": ScriptedDigPolicy(),
                                "random": RandomPolicy(seed=0)}
    assert list(episodes["policy"]) == list(policies) and list(summary["policy"]) == list(policies)
    for (_, row), (_, mean), (name, policy) in zip(episodes.iterrows(), summary.iterrows(), policies.items(),
                                                   strict=True):
        env = gym.make(scaletwin_envs.ENV_ID, scale="mini", soil="gravel", two_route_check=False)
        kpis = run_episode(env, policy, seed=0).kpis
        assert kpis is not None and (row["scale"], row["soil"], row["seed"]) == ("mini", "gravel", 0)
        for key in EPISODE_KPIS:
            assert row[key] == pytest.approx(getattr(kpis, key), rel=1e-12), (name, key)
        _check_derived(row, "mini", "gravel")
        for key in ("fill_factor", "loaded_mass", "cycle_time", "hydraulic_work", "specific_energy"):  # one episode
            assert mean[key] == pytest.approx(row[key], rel=1e-12, nan_ok=True), (name, key)
        assert (mean["success_rate"], mean["sim_errors"], mean["episodes"]) == (float(kpis.success), 0, 1)
        assert f"| {name} | mini | gravel | {kpis.fill_factor:.3f} | {kpis.loaded_mass:.4g} |" in markdown
    assert episodes.set_index("policy").loc["learned", "fill_factor"] >= 0.85  # the shipped policy fills the bucket


def test_cli_through_worker_processes(tmp_path: Path):
    """Two worker processes give the serial harness's episodes, value by value."""
    rc = main(["evaluate-policy", "--policies", "learned,scripted", "--scales", "mini", "--soils", "gravel",
               "--episodes", "1", "--workers", "2", "--out", str(tmp_path)])
    assert rc == 0
    assert len(pd.read_csv(tmp_path / "policy_kpis.csv")) == 2
    parallel = pd.read_csv(tmp_path / "policy_kpis_episodes.csv")
    serial = evaluate_policies({"learned": zoo.load("bucketfill-ppo"), "scripted": ScriptedDigPolicy()}, ["mini"],
                               ["gravel"], 1, seed=0, executor="serial")
    assert list(parallel["policy"]) == ["learned", "scripted"]
    for key in ("length_ratio", "seed", *EPISODE_KPIS, "cycle_time_froude", "specific_energy"):
        np.testing.assert_allclose(parallel[key].astype(float), serial[key].astype(float), rtol=1e-12, err_msg=key)


def test_cli_unknown_policy_is_a_clear_error(tmp_path: Path, capsys):
    rc = main(["evaluate-policy", "--policies", "nonsense", "--scales", "mini", "--episodes", "1",
               "--out", str(tmp_path)])
    assert rc == 2
    assert "nonsense" in capsys.readouterr().err


def test_cli_zoo_list_and_show(capsys):
    assert main(["zoo", "list"]) == 0
    assert "bucketfill-ppo" in capsys.readouterr().out
    assert main(["zoo", "show", "bucketfill-ppo", "--verify"]) == 0
    assert "verified" in capsys.readouterr().out
