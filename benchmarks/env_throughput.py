"""Physics throughput of WheelLoaderDig-v0: raw ``mj_step`` on the env's own model vs ``env.step``.

Both are measured side by side in one run, on the same model, over the same scripted dig cycle: the raw loop
restarts from the env's own state at every control step and runs the same physics steps with no soil update,
signals or Python in between. Also
reports the real-time factor (simulated seconds per wall second) of a full scripted cycle at each preset.

Run: ``python benchmarks/env_throughput.py [--repeats N] [--out benchmarks/results/env_throughput.md]``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import platform
import time
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np

import scaletwin_envs
from scaletwin_envs.host import host_line
from scaletwin_envs.policies import ScriptedDigPolicy
from scaletwin_envs.rollout import run_episode


def env_rate(scale: str, two_routes: bool) -> tuple[float, float, int]:
    """Physics steps per second through env.step, and the real-time factor, over one scripted cycle."""
    env = gym.make(scaletwin_envs.ENV_ID, scale=scale, two_route_check=two_routes)
    env.reset(seed=0)
    start = time.perf_counter()
    ep = run_episode(env, ScriptedDigPolicy(), seed=0)
    wall = time.perf_counter() - start
    u = env.unwrapped
    return len(ep.infos) * u.frame_skip / wall, ep.infos[-1]["time"] / wall, len(ep.infos)


def raw_rate(scale: str) -> float:
    """Raw mj_step rate on the env's own model over the same dig: from the full integration state at the start of
    every control step of a scripted cycle (load, soil dampers and controls as the env had them), step the physics
    alone for one control step's worth of steps. Only stepping is timed."""
    env = gym.make(scaletwin_envs.ENV_ID, scale=scale)
    u = env.unwrapped
    m, d = u.model, u.data
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    snapshots: list[tuple[np.ndarray, np.ndarray]] = []

    def snap(_step: int, _action: np.ndarray, _info: dict) -> None:
        state = np.empty(mujoco.mj_stateSize(m, spec))
        mujoco.mj_getState(m, d, state, spec)
        snapshots.append((state, m.tendon_damping.copy()))

    run_episode(env, ScriptedDigPolicy(), seed=0, on_step=snap)
    elapsed = 0.0
    for state, damping in snapshots:
        mujoco.mj_setState(m, d, state, spec)
        m.tendon_damping[:] = damping
        start = time.perf_counter()
        mujoco.mj_step(m, d, u.frame_skip)
        elapsed += time.perf_counter() - start
    return len(snapshots) * u.frame_skip / elapsed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="benchmarks/results/env_throughput.md")
    args = ap.parse_args()
    lines = [f"# env_throughput ({dt.date.today()}, {host_line()}, "
             f"python {platform.python_version()}, mujoco {mujoco.__version__})", "",
             "| preset | raw mj_step [steps/s] | env.step [physics steps/s] | ratio | env.step, no route-2 | ratio "
             "| real-time factor |", "|---|---|---|---|---|---|---|"]
    for scale in ("mini", "er12", "wa475"):
        best = {"env": 0.0, "fast": 0.0, "raw": 0.0, "rtf": 0.0}
        for _ in range(args.repeats):
            rate, rtf, _ = env_rate(scale, True)
            best["env"], best["rtf"] = max(best["env"], rate), max(best["rtf"], rtf)
            best["fast"] = max(best["fast"], env_rate(scale, False)[0])
            best["raw"] = max(best["raw"], raw_rate(scale))
        lines.append(f"| {scale} | {best['raw']:,.0f} | {best['env']:,.0f} | {best['env'] / best['raw']:.2f} | "
                     f"{best['fast']:,.0f} | {best['fast'] / best['raw']:.2f} | {best['rtf']:.1f} |")
    text = "\n".join(lines)
    print(text)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
