"""Dataset sweeps: the grid, one file per episode, resumable after an interrupt, parallel through the seam."""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import pandas as pd
import pytest

import scaletwin_envs.parallel as parallel
from scaletwin.cli import main
from scaletwin_envs.parallel import LocalProcessExecutor, map_in_order
from scaletwin_envs.recording import SweepSpec, load_dataset, read_recording, run_sweep
from scaletwin_envs.recording.sweep import EpisodeTask, make_policy, policy_name
from tests.parallel_tasks import interrupt_main_when, marked_sleep

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




def test_sweep_to_file_uri_and_fsspec_uri_matches_local_path(tmp_path):
    """The same sweep written to a path, a file:// URI and an fsspec memory:// URI: same files, same table."""
    fsspec = pytest.importorskip("fsspec")
    spec = SweepSpec(seeds=(0, 1), env_kwargs={"max_episode_time": 30.0})
    run_sweep(spec, tmp_path / "path", executor="serial", progress=False)
    uri = (tmp_path / "uri").as_uri()
    assert uri.startswith("file:///")
    result = run_sweep(spec, uri, executor="serial", progress=False)
    assert result.out_dir == uri and (result.ran, result.failed) == (2, 0)
    assert snapshot(tmp_path / "uri") == snapshot(tmp_path / "path")
    expected = load_dataset(tmp_path / "path")
    pd.testing.assert_frame_equal(load_dataset(uri), expected)

    memory = fsspec.filesystem("memory")
    try:
        result = run_sweep(spec, "memory://scaletwin-sweep-test/ds", executor="serial", progress=False)
        assert (result.ran, result.failed, result.out_dir) == (2, 0, "memory://scaletwin-sweep-test/ds")
        names = sorted(p.rsplit("/", 1)[-1] for p in memory.ls("/scaletwin-sweep-test/ds", detail=False))
        assert names == sorted([*snapshot(tmp_path / "path"), "manifest.json"])  # no temporary object left
        pd.testing.assert_frame_equal(load_dataset("memory://scaletwin-sweep-test/ds"), expected)
        again = run_sweep(spec, "memory://scaletwin-sweep-test/ds", executor="serial", progress=False)
        assert (again.ran, again.skipped) == (0, 2)
    finally:
        memory.rm("/scaletwin-sweep-test", recursive=True)
    with pytest.raises(ValueError, match="unsupported filesystem URI 'nosuchscheme://x'"):
        run_sweep(spec, "nosuchscheme://x", executor="serial", progress=False)


def test_ctrl_c_during_a_local_process_sweep_keeps_finished_episodes_and_stops_the_rest(tmp_path):
    """SIGINT while two worker processes record: the sweep stops at once (queued episodes never start, running ones
    are terminated), every episode finished so far stays, and a rerun records only the rest."""
    spec = SweepSpec(seeds=tuple(range(5)), policy="tests.parallel_tasks:slow_scripted",
                     policy_kwargs={"delay": 0.005}, env_kwargs={"max_episode_time": 30.0})
    interrupt_main_when(lambda: any(tmp_path.glob("ep-*.parquet")))
    with pytest.raises(KeyboardInterrupt):
        run_sweep(spec, tmp_path, executor=LocalProcessExecutor(2), progress=False)
    stopped = time.monotonic()
    first = snapshot(tmp_path)
    assert 1 <= len(first) < 5
    for name in first:
        assert read_recording(tmp_path / name).provenance.extra["sweep_task"]["key"] == name[3:-8]
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    done = {e["file"] for e in manifest["episodes"].values() if e["status"] == "done"}
    assert done <= set(first)  # every episode reported finished is on disk (one whose file is written but whose
    # result had not reached the driver when the interrupt came is on disk, not yet in the manifest: the rerun skips it)
    time.sleep(max(0.0, stopped + 1.5 - time.monotonic()))  # longer than one episode: nothing still running
    assert snapshot(tmp_path) == first

    result = run_sweep(spec, tmp_path, executor="serial", progress=False)
    assert (result.ran, result.skipped, result.failed) == (5 - len(first), len(first), 0)
    second = snapshot(tmp_path)
    assert len(second) == 5 and all(second[name] == data for name, data in first.items())


def test_local_processes_yield_results_finished_when_interrupted(tmp_path, monkeypatch):
    """Ctrl-C arriving while results are waited for: the ones already finished still come out, then the interrupt."""
    real_wait = parallel.futures_wait
    calls = []

    def interrupted_wait(pending, timeout=None, return_when=None):
        calls.append(len(pending))
        if len(calls) == 1:
            real_wait(pending)  # every task finishes while we "wait" ...
            raise KeyboardInterrupt  # ... and the interrupt arrives before they are handed out
        return real_wait(pending, timeout, return_when)

    monkeypatch.setattr(parallel, "futures_wait", interrupted_wait)
    got = []
    with pytest.raises(KeyboardInterrupt):
        for i, result in LocalProcessExecutor(2).map_unordered(marked_sleep, [(str(tmp_path), i, 0.0)
                                                                               for i in range(3)]):
            got.append((i, result))
    assert got == [(0, 0), (1, 1), (2, 2)] and calls == [3]


def test_map_in_order_and_cancel_on_error(tmp_path):
    jobs = [(str(tmp_path), i, 0.3 * (2 - i)) for i in range(3)]  # the last finishes first
    assert map_in_order(marked_sleep, jobs, LocalProcessExecutor(2)) == [0, 1, 2]
    assert map_in_order(marked_sleep, jobs[:1]) == [0]
    with pytest.raises(TypeError):
        map_in_order(marked_sleep, [(str(tmp_path), 9, "not a number"), *[(str(tmp_path), 10 + i, 5.0)
                                                                          for i in range(3)]], 2)
    time.sleep(0.2)
    assert not (tmp_path / "start-12").exists()  # queued behind the error: never started
    assert not (tmp_path / "end-10").exists() and not (tmp_path / "end-11").exists()


def test_executor_options_of_the_commands(tmp_path, capsys, monkeypatch):
    """Contradictory executor options fail at once with exit code 2; without Ray installed, --executor ray says what
    to install instead of a traceback."""
    cases = [(["dataset", str(tmp_path), "--executor", "serial", "--workers", "2"], "--workers applies to local"),
             (["dataset", str(tmp_path), "--ray-cpus", "2"], "--ray-cpus applies to --executor ray only"),
             (["product-line", str(tmp_path), "--executor", "local", "--ray-address", "auto"], "--ray-address"),
             (["fit", "--executor", "ray", "--workers", "3"], "--workers applies to local processes only"),
             (["reproduce", "--executor", "ray", "--ray-cpus", "0"], "--ray-cpus must be > 0")]
    for argv, message in cases:
        assert main(argv) == 2, argv
        assert message in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "ray", None)  # as if Ray were not installed
    assert main(["dataset", str(tmp_path), "--no-progress", "--ray-address", "auto"]) == 2
    assert 'pip install "scaletwin[ray]"' in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_episode_key_follows_the_machine_a_preset_names(monkeypatch: pytest.MonkeyPatch) -> None:
    """A resumed sweep must not keep an episode recorded with an older version of a preset: the task's key (its
    file name) holds the machine the name stood for, and so does a length ratio (scaled from the ER12 preset)."""
    from dataclasses import replace

    from scaletwin_envs.specs import presets

    task = EpisodeTask(scale="wa475", soil="gravel", pile_distance=0.5, pile_height=0.6, seed=0)
    ratio = EpisodeTask(scale=1.5, soil="gravel", pile_distance=0.5, pile_height=0.6, seed=0)
    before = task.key(), ratio.key()
    assert task.key() == before[0]  # stable
    wa, er = presets.PRESETS["wa475"], presets.PRESETS["er12"]
    monkeypatch.setitem(presets.PRESETS, "wa475", replace(wa, travel_speed=wa.travel_speed * 1.1))
    monkeypatch.setitem(presets.PRESETS, "er12", replace(er, traction_coefficient=0.55))
    assert task.key() != before[0]
    assert ratio.key() != before[1]


def test_loaded_order_follows_the_episodes_not_their_file_names(tmp_path):
    """Analyses sample rows by position; the hash names of the files must not decide the order."""
    import shutil

    first, second = tmp_path / "a", tmp_path / "b"
    run_sweep(SweepSpec(scales=("mini", 0.2), seeds=(0, 1)), first, executor="serial", progress=False)
    names = sorted(p.name for p in first.glob("ep-*.parquet"))
    second.mkdir()
    for old, new in zip(names, reversed(names), strict=True):  # same episodes under each other's names
        shutil.copy(first / old, second / new)
    a, b = load_dataset(first), load_dataset(second)
    pd.testing.assert_frame_equal(a, b)
    order = a.drop_duplicates("episode")[["machine", "seed"]].apply(tuple, axis=1).tolist()
    assert order == sorted(order)


def test_episode_key_follows_the_simulation_code() -> None:
    """An episode recorded by other simulation code is never reused: the key holds the code's digest, which a task
    takes from the process that makes it and carries to the workers."""
    import pickle
    from dataclasses import replace

    import scaletwin_envs.recording.sweep as sweep

    task = EpisodeTask(scale={"name": "x"}, soil="gravel", pile_distance=0.5, pile_height=0.6, seed=0)
    digest = sweep.simulation_digest()
    assert len(digest) == 16 and task.simulation == digest == sweep.simulation_digest()
    assert replace(task, simulation="0" * 16).key() != task.key()
    assert pickle.loads(pickle.dumps(task)).key() == task.key()  # what a worker process sees
