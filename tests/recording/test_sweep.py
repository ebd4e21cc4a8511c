"""Dataset sweeps: the grid, one file per episode, resumable after an interrupt, parallel through the seam."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import pytest

from scaletwin.cli import main
from scaletwin_envs.parallel import LocalProcessExecutor
from scaletwin_envs.recording import SweepSpec, load_dataset, read_recording, run_sweep
from scaletwin_envs.recording.sweep import EpisodeTask, make_policy, policy_name

SPEC = SweepSpec(scales=("mini", 0.2), soils=("gravel",), pile_distances=(0.4,), pile_heights=(0.6, 0.7),
                 seeds=(0,), env_kwargs={"max_episode_time": 30.0})


class InterruptAfter:
    """An executor that runs tasks serially and is interrupted (Ctrl-C) while running task ``n``."""

    def __init__(self, n: int) -> None:
        self.n = n

    def map_unordered(self, fn: Callable, tasks: Sequence) -> Iterator[tuple[int, Any]]:
        for i, task in enumerate(tasks):
            if i == self.n:
                raise KeyboardInterrupt
            yield i, fn(task)


def snapshot(folder) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.suffix == ".parquet"}


def test_grid_is_stable_and_named_by_hash():
    tasks = SPEC.tasks()
    assert len(tasks) == 4 and len({t.key() for t in tasks}) == 4
    assert [t.key() for t in tasks] == [t.key() for t in SPEC.tasks()]
    assert tasks[0].filename == f"ep-{tasks[0].key()}.parquet"
    twice = SweepSpec(scales=("mini", "mini"), seeds=(0, 0))
    assert len(twice.tasks()) == 1
    assert EpisodeTask("mini", "gravel", 0.5, 0.7, 1).key() != EpisodeTask("mini", "gravel", 0.5, 0.7, 2).key()


def test_interrupted_sweep_resumes_without_duplicates_or_losses(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        run_sweep(SPEC, tmp_path, executor=InterruptAfter(2), progress=False)
    first = snapshot(tmp_path)
    assert len(first) == 2
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert sorted(e["status"] for e in manifest["episodes"].values()) == ["done", "done", "pending", "pending"]
    (tmp_path / ".ep-0000.parquet.123.ab.tmp").write_bytes(b"partial")  # a write killed mid-way

    result = run_sweep(SPEC, tmp_path, executor="serial", progress=False)
    assert (result.ran, result.skipped, result.failed) == (2, 2, 0)
    second = snapshot(tmp_path)
    assert len(second) == 4 and all(second[name] == data for name, data in first.items())
    assert run_sweep(SPEC, tmp_path, executor="serial", progress=False).ran == 0

    data = load_dataset(tmp_path)
    assert data["episode"].nunique() == 4
    assert len(data) == sum(len(read_recording(tmp_path / name)) for name in second)
    assert not data.duplicated(["episode", "step"]).any()
    assert set(data["machine"]) == {"mini", "product_line(scale=0.2)"}
    assert set(data["pile_height"]) == {0.6, 0.7}
    assert data.attrs["units"]["F21"] == "N"
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert {e["status"] for e in manifest["episodes"].values()} == {"done"}
    assert manifest["package_version"] and manifest["spec"]["scales"] == ["mini", 0.2]


def test_episode_files_carry_their_task(tmp_path):
    run_sweep(SweepSpec(seeds=(3,)), tmp_path, executor="serial", progress=False)
    (path,) = tmp_path.glob("ep-*.parquet")
    prov = read_recording(path).provenance
    assert prov.seed == 3 and prov.extra["sweep_task"]["key"] == path.stem[3:]


def test_two_processes_and_policy_factory_string(tmp_path):
    spec = SweepSpec(seeds=(0, 1), policy="scaletwin_envs.policies.scripted:ScriptedDigPolicy",
                     policy_kwargs={"penetration": 0.4})
    result = run_sweep(spec, tmp_path, executor=LocalProcessExecutor(2), progress=False)
    assert (result.ran, result.failed) == (2, 0)
    assert "penetration=0.4" in read_recording(next(tmp_path.glob("ep-*.parquet"))).provenance.policy


def test_failures_are_reported_and_retried(tmp_path):
    result = run_sweep(SweepSpec(soils=("lava",)), tmp_path, executor="serial", progress=False)
    assert result.failed == 1
    (entry,) = result.manifest["episodes"].values()
    assert entry["status"] == "failed" and "soil must be one of" in entry["error"]
    assert not list(tmp_path.glob("ep-*.parquet"))


def test_policy_strings():
    assert make_policy("scripted", penetration=0.3).penetration == 0.3
    with pytest.raises(ValueError, match="module:function"):
        make_policy("learned")
    assert policy_name(make_policy) == "scaletwin_envs.recording.sweep:make_policy"
    with pytest.raises(ValueError, match="not importable"):
        policy_name(lambda: None)


def test_dataset_cli(tmp_path, capsys):
    out = tmp_path / "ds"
    assert main(["dataset", str(out), "--scales", "mini", "--episodes", "2", "--workers", "1", "--no-progress"]) == 0
    assert "2 recorded, 0 already present, 0 failed" in capsys.readouterr().out
    assert main(["dataset", str(out), "--scales", "mini", "--episodes", "2", "--workers", "1", "--no-progress"]) == 0
    assert "0 recorded, 2 already present" in capsys.readouterr().out
    assert main(["dataset", str(out), "--soils", "lava", "--workers", "1", "--no-progress"]) == 1
    with pytest.raises(FileNotFoundError):
        load_dataset(tmp_path / "empty")
