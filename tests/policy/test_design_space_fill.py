"""Dig policies on a machine sampled from the product-line design space, through the KPI harness and the helpers of
``benchmarks/design_space_fill.py`` (one scripted episode on one held-out machine)."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path
from types import ModuleType

import gymnasium as gym
import pandas as pd
import pytest

import scaletwin_envs
from scaletwin_envs.design_space import DesignSpace, ProductLineMachine
from scaletwin_envs.evaluation import evaluate_policies
from scaletwin_envs.policies import TUNED, ScriptedDigPolicy

BENCHMARK = Path(__file__).resolve().parents[2] / "benchmarks" / "design_space_fill.py"


def _benchmark() -> ModuleType:
    spec = importlib.util.spec_from_file_location("design_space_fill", BENCHMARK)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    return _benchmark()


@pytest.fixture(scope="module")
def machine(bench: ModuleType) -> ProductLineMachine:
    return DesignSpace().sample_one(bench.HELD_OUT_SEED, 0)


@pytest.fixture(scope="module")
def episode(machine: ProductLineMachine) -> pd.DataFrame:
    return evaluate_policies({"scripted-tuned": ScriptedDigPolicy(**TUNED)}, [machine.spec], ["gravel"], episodes=1,
                             executor="serial")


def test_env_builds_the_sampled_machine(machine: ProductLineMachine):
    env = gym.make(scaletwin_envs.ENV_ID, scale=machine.spec, soil="gravel", two_route_check=False)
    try:
        assert env.unwrapped.loader == machine.spec
    finally:
        env.close()


def test_kpi_row_is_sane(machine: ProductLineMachine, episode: pd.DataFrame):
    """One row, labelled by the machine's name, with its λ, a finite fill in [0, 1.3], no physics error."""
    assert len(episode) == 1
    row = episode.iloc[0]
    assert row["scale"] == machine.name and row["policy"] == "scripted-tuned" and row["soil"] == "gravel"
    assert row["length_ratio"] == pytest.approx(machine.scale, rel=1e-12)
    assert math.isfinite(row["fill_factor"]) and 0.0 <= row["fill_factor"] <= 1.3
    assert row["sim_error"] is None and row["steps"] > 0 and row["cycle_time"] > 0


def test_benchmark_tables_and_replay(bench: ModuleType, machine: ProductLineMachine, episode: pd.DataFrame,
                                     tmp_path: Path):
    """Per-machine table and tally from the episode rows; the shortfall replay reproduces the evaluated fill."""
    info = bench.machine_table([machine])
    assert info.loc[0, "machine"] == machine.name and info.loc[0, "mass_t"] == pytest.approx(
        machine.spec.operating_mass / 1000.0)
    rows = episode.rename(columns={"scale": "machine"})
    table = bench.per_machine(rows, info)
    assert len(table) == 1 and table.loc[0, "fill_min"] == table.loc[0, "fill_mean"] == rows.loc[0, "fill_factor"]
    counts = bench.tally(table, target=0.0)
    assert counts.loc[0, "machines"] == counts.loc[0, "min_ok"] == 1
    policies = {"scripted-tuned": ScriptedDigPolicy(**TUNED)}
    short = bench.diagnose_shortfalls(rows, [machine], policies, target=2.0)  # every episode counts as short
    assert len(short) == 1 and short.loc[0, "fill"] == rows.loc[0, "fill_factor"]
    assert short.loc[0, "fill_peak"] >= short.loc[0, "fill"] and 0.0 <= short.loc[0, "stall_share"] <= 1.0
    md = bench.write_markdown(tmp_path / "r.md", header=["# t"], machines=info, table=table,
                              counts=bench.tally(table), shortfalls=short, target=bench.TARGET_FILL).read_text()
    assert machine.name in md and "## Shortfalls" in md
