"""Cost of recording a dig episode, and the throughput of a dataset sweep on 1 and 2 processes.

Part 1, side by side in one run on the same env and seeds (modes interleaved, best of ``--repeats`` per seed):
plain ``run_episode``; recording in the loop only (``record_episode``); recording + Parquet file (target: at
most 20 % over plain); rerun logging to an ``.rrd`` file. Part 2: the same sweep run serially and on 2 local
processes (process start-up included), giving the scaling ratio.

Run: ``python benchmarks/recording_overhead.py [--seeds N] [--repeats N] [--sweep-episodes N]
[--out benchmarks/results/recording_overhead.md]``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import pyarrow
import rerun as rr

import scaletwin_envs
from scaletwin_envs.host import host_line
from scaletwin_envs.parallel import Executor, LocalProcessExecutor, SerialExecutor
from scaletwin_envs.policies import ScriptedDigPolicy
from scaletwin_envs.recording import SweepSpec, record_episode, run_sweep
from scaletwin_envs.recording.rerun_log import RerunLogger, open_stream
from scaletwin_envs.rollout import run_episode

MODES = ("plain", "record", "record + parquet", "rerun .rrd")
PARQUET_TARGET = 1.20


def episode_modes(env: gym.Env, folder: Path) -> dict[str, Callable[[int], int]]:
    """Each mode runs one scripted episode with the given seed and returns its number of steps."""

    def plain(seed: int) -> int:
        return len(run_episode(env, ScriptedDigPolicy(), seed=seed).infos)

    def record(seed: int) -> int:
        return len(record_episode(env, ScriptedDigPolicy(), seed))

    def parquet(seed: int) -> int:
        rec = record_episode(env, ScriptedDigPolicy(), seed)
        rec.to_parquet(folder / f"ep{seed}.parquet")
        return len(rec)

    def rerun_file(seed: int) -> int:
        stream = open_stream(folder / f"ep{seed}.rrd")
        logger = RerunLogger(env, stream)
        steps = len(run_episode(env, ScriptedDigPolicy(), seed=seed, on_step=logger).infos)
        logger.close()
        stream.disconnect()
        return steps

    return dict(zip(MODES, (plain, record, parquet, rerun_file), strict=True))


def time_modes(scale: str, seeds: int, repeats: int) -> tuple[dict[str, float], dict[str, float], int]:
    """Wall and CPU time (s, all threads of this process) per mode, summed over the seeds (best of ``repeats``
    per seed, each clock on its own), and the steps of one pass over the seeds."""
    env = gym.make(scaletwin_envs.ENV_ID, scale=scale)
    wall = {(m, s): float("inf") for m in MODES for s in range(seeds)}
    cpu = dict(wall)
    steps = 0
    with tempfile.TemporaryDirectory() as tmp:
        modes = episode_modes(env, Path(tmp))
        for fn in modes.values():  # warm-up: imports, first pyarrow/rerun calls
            fn(0)
        for _ in range(repeats):
            for seed in range(seeds):
                for mode, fn in modes.items():
                    w, c = time.perf_counter(), time.process_time()
                    n = fn(seed)
                    wall[mode, seed] = min(wall[mode, seed], time.perf_counter() - w)
                    cpu[mode, seed] = min(cpu[mode, seed], time.process_time() - c)
                    steps += n if mode == "plain" else 0
    def total(t: dict) -> dict[str, float]:
        return {m: sum(t[m, s] for s in range(seeds)) for m in MODES}

    return total(wall), total(cpu), steps // repeats


class Timed:
    """Wraps an executor and notes the time of every completed episode."""

    def __init__(self, inner: Executor) -> None:
        self.inner, self.done = inner, []

    def map_unordered(self, fn: Callable, tasks: Sequence) -> Iterator[tuple[int, Any]]:
        for item in self.inner.map_unordered(fn, tasks):
            self.done.append(time.perf_counter())
            yield item


def sweep_rate(workers: int, episodes: int) -> dict[str, float]:
    """A fresh sweep of ``episodes`` mini/er12 digs: wall time (s), episodes/s including process start-up,
    and episodes/s after the first episode per process finished (steady state)."""
    spec = SweepSpec(scales=("mini", "er12"), seeds=tuple(range(max(workers, episodes // 2))))
    timed = Timed(SerialExecutor() if workers == 1 else LocalProcessExecutor(workers))
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        result = run_sweep(spec, tmp, executor=timed, progress=False)
        wall = time.perf_counter() - start
    if result.failed:
        raise RuntimeError(f"{result.failed} sweep episodes failed")
    warm = timed.done[workers - 1]  # by then every process has started and finished one episode
    return {"wall": wall, "rate": result.ran / wall, "steady": (result.ran - workers) / (timed.done[-1] - warm),
            "episodes": result.ran}


def _plain_episodes(n: int) -> float:
    """Wall time of ``n`` plain er12 episodes in this process (after one warm-up episode)."""
    env = gym.make(scaletwin_envs.ENV_ID, scale="er12")
    run_episode(env, ScriptedDigPolicy(), seed=0)
    start = time.perf_counter()
    for seed in range(n):
        run_episode(env, ScriptedDigPolicy(), seed=seed)
    return time.perf_counter() - start


def cpu_parallelism(n: int = 8) -> float:
    """Speed-up of 2 processes over 1 running plain episodes (no recording, no sweep): what the machine offers
    right now, with whatever else shares its cores."""
    with ProcessPoolExecutor(2, mp_context=get_context("spawn")) as pool:
        list(pool.map(_plain_episodes, [1, 1]))  # start both workers
        one = next(pool.map(_plain_episodes, [n]))
        two = max(pool.map(_plain_episodes, [n, n]))
    return 2 * one / two


def header() -> list[str]:
    now = dt.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z")
    return [f"# recording_overhead ({now})", "",
            f"Machine: {host_line()}; python {platform.python_version()}, mujoco {mujoco.__version__}, "
            f"pyarrow {pyarrow.__version__}, rerun-sdk {rr.__version__}, scaletwin {scaletwin_envs.__version__}.", ""]


def overhead_table(seeds: int, repeats: int) -> list[str]:
    lines = [f"## Episode recording overhead (scripted dig, {seeds} seeds, best of {repeats})", "",
             "| preset | steps/episode | " + " | ".join(f"{m} [ms/episode]" for m in MODES)
             + " | record | record + parquet | rerun .rrd |", "|---|---|" + "---|" * (len(MODES) + 3)]
    worst = 0.0
    for scale in ("mini", "er12", "wa475"):
        wall, cpu, steps = time_modes(scale, seeds, repeats)
        ratio = {m: f"{cpu[m] / cpu['plain']:.3f} ({wall[m] / wall['plain']:.3f})" for m in MODES[1:]}
        worst = max(worst, cpu["record + parquet"] / cpu["plain"])
        lines.append(f"| {scale} | {steps / seeds:.0f} | "
                     + " | ".join(f"{1e3 * wall[m] / seeds:.1f}" for m in MODES) + " | "
                     + " | ".join(ratio[m] for m in MODES[1:]) + " |")
    verdict = "met" if worst <= PARQUET_TARGET else "NOT met"
    lines += ["", "Times are wall clock; ratios over plain `run_episode` are CPU time of the process (all threads, "
              "so rerun's and Arrow's writer threads count), wall-time ratio in brackets. CPU time is what recording "
              "costs; wall time also holds whatever else ran on the shared cores. "
              f"Parquet target ≤ {PARQUET_TARGET:.2f} (CPU): {verdict} (worst {worst:.3f}). "
              f"`uptime` load at the end: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores.", ""]
    return lines


def sweep_table(episodes: int) -> list[str]:
    before = cpu_parallelism()
    one, two = sweep_rate(1, episodes), sweep_rate(2, episodes)
    after = cpu_parallelism()
    rows = [f"| {name} | {r['wall']:.2f} | {r['rate']:.2f} | {r['steady']:.2f} |"
            for name, r in (("1 (serial)", one), ("2 (local processes, spawn)", two))]
    return [f"## Sweep throughput ({one['episodes']} episodes: mini and er12, scripted, one Parquet file each)", "",
            "| processes | wall [s] | episodes/s (with start-up) | episodes/s (steady) |", "|---|---|---|---|", *rows,
            "", f"Scaling ratio, 2 vs 1 process: {two['rate'] / one['rate']:.2f} with process start-up, "
            f"{two['steady'] / one['steady']:.2f} steady (ideal 2.00). Ceiling: 2 processes running plain episodes "
            f"(no recording, no sweep) were {before:.2f}× / {after:.2f}× as fast as 1, just before / after "
            f"(`uptime` load {os.getloadavg()[0]:.1f}: the cores are shared with other work).", ""]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--sweep-episodes", type=int, default=40)
    ap.add_argument("--out", default="benchmarks/results/recording_overhead.md")
    args = ap.parse_args()
    os.environ.setdefault("CI", "1")  # no rerun analytics
    text = "\n".join(header() + overhead_table(args.seeds, args.repeats) + sweep_table(args.sweep_episodes))
    print(text)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
