"""The executor seam on a real local Ray (``ray.init(num_cpus=2)``, one session for the module, ~5 s to start):
a sweep and a grid search give exactly what local processes give, outputs go through a file:// URI, Ctrl-C cancels
the tasks and keeps every finished result, the command line reaches Ray."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

ray = pytest.importorskip("ray", reason='Ray is not installed (pip install -e ".[dev]" or "scaletwin[ray]")')

from scaletwin.cli import main  # noqa: E402
from scaletwin_envs.parallel import LocalProcessExecutor, RayExecutor, make_executor, map_in_order  # noqa: E402
from scaletwin_envs.recording import SweepSpec, load_dataset, run_sweep  # noqa: E402
from tests.parallel_tasks import interrupt_main_when, marked_sleep  # noqa: E402

SPEC = SweepSpec(scales=("mini", 0.2), seeds=(0, 1), env_kwargs={"max_episode_time": 30.0})


@pytest.fixture(scope="module", autouse=True)
def ray_session() -> Iterator[None]:
    """One local Ray of two CPUs for every test of this module (a Ray this process already runs is reused)."""
    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield
    if started:
        ray.shutdown()


def parquet_bytes(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.glob("ep-*.parquet"))}




def test_sweep_on_ray_to_a_file_uri_equals_local_processes(tmp_path: Path) -> None:
    """Ray workers write the episodes through a file:// URI; the files are byte for byte those of local processes."""
    local = run_sweep(SPEC, tmp_path / "local", executor=LocalProcessExecutor(2), progress=False)
    uri = (tmp_path / "ray").as_uri()
    on_ray = run_sweep(SPEC, uri, executor=RayExecutor(), progress=False)
    assert (local.ran, local.failed) == (on_ray.ran, on_ray.failed) == (4, 0)
    files = parquet_bytes(tmp_path / "local")
    assert len(files) == 4 and parquet_bytes(tmp_path / "ray") == files
    pd.testing.assert_frame_equal(load_dataset(uri), load_dataset(tmp_path / "local"), check_exact=True)
    manifest = json.loads((tmp_path / "ray" / "manifest.json").read_text())
    assert {e["status"] for e in manifest["episodes"].values()} == {"done"}
    assert run_sweep(SPEC, uri, executor=RayExecutor(), progress=False).skipped == 4


def test_grid_search_on_ray_equals_local_processes() -> None:
    """The same small grid through Ray and in this process: the same table, value by value. Local processes give
    this process's table too (tests/scaling/test_grid.py::test_grid_search_through_local_processes, same grid and
    data); comparing with them here again would cost ~20 s of process start-up on two cores."""
    from scaling.data.delta_dataset import DeltaDataset
    from scaling.models.grid import GridSearch
    from tests.scaling.test_factors import INPUTS, PI1, synthetic_recordings

    rec = synthetic_recordings(episodes=(4, 4), steps=30, seed=1)
    train, test = DeltaDataset.from_recordings(rec, PI1, INPUTS).split_by_episode(0.25)
    grid = {"hidden_layers": (1,), "units": (4, 8, 16), "dropout": (0.0,), "lr": (1e-2,)}
    base = {"epochs": 5, "threads": 1}
    on_ray = GridSearch(grid=grid, base_config=base, executor=RayExecutor(), progress=False).run(train, test)
    local = GridSearch(grid=grid, base_config=base, executor="serial", progress=False).run(train, test)
    assert list(on_ray["units"]) == [4, 8, 16] and np.isfinite(on_ray["r2"]).all()
    pd.testing.assert_frame_equal(on_ray.drop(columns="fit_s"), local.drop(columns="fit_s"), check_exact=True)


def test_ctrl_c_cancels_queued_and_running_ray_tasks(tmp_path: Path) -> None:
    """Two quick tasks, then four of 3 s on two CPUs: SIGINT once the quick ones are in stops everything at once;
    no slow task ever finishes (running ones are cancelled, queued ones never start)."""
    jobs = [(str(tmp_path), i, 0.0 if i < 2 else 3.0) for i in range(6)]
    got: list[int] = []
    interrupt_main_when(lambda: len(got) == 2 and (tmp_path / "start-2").exists())
    start = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        for _, result in RayExecutor().map_unordered(marked_sleep, jobs):
            got.append(result)
    assert sorted(got) == [0, 1]
    assert time.monotonic() - start < 3.0  # did not wait for the slow tasks
    time.sleep(max(0.0, start + 4.0 - time.monotonic()))  # past the end of any slow task left running
    assert not list(tmp_path.glob("end-[2-5]"))
    assert len(list(tmp_path.glob("start-*"))) <= 4  # at most the two that were running when interrupted


def test_results_finished_before_the_interrupt_are_still_yielded(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    real_wait = ray.wait
    calls: list[int] = []

    def interrupted_wait(refs, *, num_returns=1, timeout=None, **kwargs):
        calls.append(len(refs))
        if len(calls) == 1:
            real_wait(refs, num_returns=len(refs))  # every task finishes while we "wait" ...
            raise KeyboardInterrupt  # ... and the interrupt arrives before they are handed out
        return real_wait(refs, num_returns=num_returns, timeout=timeout, **kwargs)

    monkeypatch.setattr(ray, "wait", interrupted_wait)
    got = []
    with pytest.raises(KeyboardInterrupt):
        for item in RayExecutor().map_unordered(marked_sleep, [(str(tmp_path), i, 0.0) for i in range(3)]):
            got.append(item)
    assert got == [(0, 0), (1, 1), (2, 2)] and calls[0] == 3


def test_ray_executor_options_errors_and_order(tmp_path: Path) -> None:
    ex = RayExecutor(num_cpus=0.5, resources={"sim_node": 1}, max_retries=0)
    assert ex.remote_options == {"num_cpus": 0.5, "num_gpus": 0.0, "resources": {"sim_node": 1}, "max_retries": 0}
    with pytest.raises(ValueError, match="num_cpus must be >= 0"):
        RayExecutor(num_cpus=-1)
    assert isinstance(make_executor("ray"), RayExecutor) and not RayExecutor().multi_node()
    jobs = [(str(tmp_path), i, 0.2 * (3 - i)) for i in range(4)]  # the last finishes first
    assert map_in_order(marked_sleep, jobs, RayExecutor(num_cpus=0.5)) == [0, 1, 2, 3]
    with pytest.raises(TypeError):  # the task's own error type comes through
        map_in_order(marked_sleep, [(str(tmp_path), 9, "not a number")], RayExecutor())


def test_cli_dataset_and_grid_command_on_ray(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    uri = (tmp_path / "ds").as_uri()
    args = ["dataset", uri, "--scales", "mini", "--episodes", "2", "--no-progress", "--executor", "ray"]
    assert main([*args, "--ray-cpus", "1"]) == 0
    assert "2 recorded, 0 already present, 0 failed" in capsys.readouterr().out
    assert len(list((tmp_path / "ds").glob("ep-*.parquet"))) == 2
    assert main([*args[:-2], "--ray-address", "auto"]) == 0  # the address implies Ray; this Ray is reused
    assert "0 recorded, 2 already present" in capsys.readouterr().out
    assert main([*args, "--workers", "2"]) == 2
    assert "--workers" in capsys.readouterr().err


def test_cli_product_line_on_ray_to_a_file_uri(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from scaling.data.recordings import load_recordings

    uri = (tmp_path / "line").as_uri()
    argv = ["product-line", uri, "--machines", "1", "--soils", "gravel", "--holds", "0", "--executor", "ray"]
    assert main(argv) == 0
    capsys.readouterr()
    frame = load_recordings(uri)
    files = list((tmp_path / "line").glob("ep-*.parquet"))
    assert files and frame["episode_key"].nunique() == len(files)
    assert (tmp_path / "line" / "machines.json").exists() and (tmp_path / "line" / "scaling.json").exists()
