"""The KPI harness (function and CLI) on tiny runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from scaletwin.cli import main
from scaletwin_envs.evaluation import KPI_COLUMNS, evaluate_policies, plot_kpis, summarize, write_csv, write_markdown
from scaletwin_envs.policies import RandomPolicy, ScriptedDigPolicy


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


def test_cli_writes_table_files(tmp_path: Path, capsys):
    rc = main(["evaluate-policy", "--policies", "learned,scripted,random", "--scales", "mini", "--soils", "gravel",
               "--episodes", "1", "--workers", "serial", "--out", str(tmp_path)])
    assert rc == 0
    out = capsys.readouterr().out
    assert "learned" in out and "scripted" in out and "random" in out
    for name in ("policy_kpis.md", "policy_kpis.csv", "policy_kpis_episodes.csv", "policy_kpis.png"):
        assert (tmp_path / name).is_file(), name


def test_cli_through_worker_processes(tmp_path: Path):
    rc = main(["evaluate-policy", "--policies", "learned,scripted", "--scales", "mini", "--soils", "gravel",
               "--episodes", "1", "--workers", "2", "--out", str(tmp_path)])
    assert rc == 0
    assert len(pd.read_csv(tmp_path / "policy_kpis.csv")) == 2


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
