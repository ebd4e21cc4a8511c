"""Physics throughput of WheelLoaderDig-v0: raw ``mj_step`` on the env's own model vs ``env.step``.

Both are measured side by side in one run, on the same model, over a scripted dig cycle: the raw loop replays
the same number of physics steps from the env's own states, with no soil, signals or Python in between. Also
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

import scaletwin_envs
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


def raw_rate(scale: str, steps: int) -> float:
    """Raw mj_step rate on the env's model, from states visited during a dig (load in the bucket, in the pile)."""
    env = gym.make(scaletwin_envs.ENV_ID, scale=scale)
    obs, _ = env.reset(seed=0)
    policy = ScriptedDigPolicy()
    for _ in range(40):
        obs, *_ = env.step(policy(obs))
    m, d = env.unwrapped.model, env.unwrapped.data
    start = time.perf_counter()
    mujoco.mj_step(m, d, steps)
    return steps / (time.perf_counter() - start)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="benchmarks/results/env_throughput.md")
    args = ap.parse_args()
    lines = [f"# env_throughput ({dt.date.today()}, {platform.processor() or platform.machine()}, "
             f"python {platform.python_version()}, mujoco {mujoco.__version__})", "",
             "| preset | raw mj_step [steps/s] | env.step [physics steps/s] | ratio | env.step, no route-2 | ratio "
             "| real-time factor |", "|---|---|---|---|---|---|---|"]
    for scale in ("mini", "er12", "wa475"):
        best = {"env": 0.0, "fast": 0.0, "raw": 0.0, "rtf": 0.0}
        for _ in range(args.repeats):
            rate, rtf, steps = env_rate(scale, True)
            best["env"], best["rtf"] = max(best["env"], rate), max(best["rtf"], rtf)
            best["fast"] = max(best["fast"], env_rate(scale, False)[0])
            best["raw"] = max(best["raw"], raw_rate(scale, steps * 100))
        lines.append(f"| {scale} | {best['raw']:,.0f} | {best['env']:,.0f} | {best['env'] / best['raw']:.2f} | "
                     f"{best['fast']:,.0f} | {best['fast'] / best['raw']:.2f} | {best['rtf']:.1f} |")
    text = "\n".join(lines)
    print(text)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
