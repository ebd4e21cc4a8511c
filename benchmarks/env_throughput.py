"""Physics throughput of WheelLoaderDig-v0: raw ``mj_step`` on the env's own model vs ``env.step``.

Both are measured side by side in one run, on the same model, over the same scripted dig cycle: the raw loop
restarts from the env's own state at every control step and runs the same physics steps with no soil update,
signals or Python in between. Also reports the real-time factor (simulated seconds per wall second) of a full
scripted cycle at each preset, and the bound ``mj_step`` alone puts on it (timestep × raw steps per second).

``--baseline DIR`` also measures another checkout of ``scaletwin_envs`` (e.g. ``git archive REV scaletwin_envs |
tar -x -C DIR``) in the same run: every repeat measures each tree in turn, in fresh processes, so both see the same
machine load; the best of the repeats is reported (a busy machine only ever slows a run down).

Run: ``python benchmarks/env_throughput.py [--repeats N] [--baseline DIR] [--out FILE]`` (default FILE:
``benchmarks/results/env_throughput.md``).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCALES = ("mini", "er12", "wa475")


def measure(scale: str) -> dict[str, float]:
    """One measurement of every rate at ``scale`` in this process (imports the scaletwin_envs first on sys.path)."""
    import gymnasium as gym
    import mujoco
    import numpy as np

    import scaletwin_envs
    from scaletwin_envs.policies import ScriptedDigPolicy
    from scaletwin_envs.rollout import run_episode

    def env_rate(two_routes: bool) -> tuple[float, float, float]:
        """Physics steps per second through env.step, real-time factor, timestep (s), over one scripted cycle."""
        env = gym.make(scaletwin_envs.ENV_ID, scale=scale, two_route_check=two_routes)
        env.reset(seed=0)
        start = time.perf_counter()
        ep = run_episode(env, ScriptedDigPolicy(), seed=0)
        wall = time.perf_counter() - start
        u = env.unwrapped
        return len(ep.infos) * u.frame_skip / wall, ep.infos[-1]["time"] / wall, float(u.model.opt.timestep)

    def raw_rate() -> float:
        """Raw mj_step rate on the env's own model over the same dig: from the full integration state at the start
        of every control step of a scripted cycle (load, soil dampers and controls as the env had them), step the
        physics alone for one control step's worth of steps. Only stepping is timed."""
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

    env, rtf, timestep = env_rate(True)
    fast = env_rate(False)[0]
    raw = raw_rate()
    return {"env": env, "rtf": rtf, "fast": fast, "raw": raw, "timestep": timestep}


def measure_in_subprocess(tree: Path, scale: str) -> dict[str, float]:
    """:func:`measure` in a fresh interpreter with ``tree`` first on sys.path (its scaletwin_envs is measured)."""
    code = (f"import sys, json; sys.path.insert(0, {str(tree)!r}); sys.path.insert(1, {str(ROOT / 'benchmarks')!r}); "
            f"import scaletwin_envs; assert scaletwin_envs.__file__.startswith({str(tree)!r}), "
            f"scaletwin_envs.__file__; import env_throughput; print(json.dumps(env_throughput.measure({scale!r})))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=tree)
    return json.loads(out.stdout.strip().splitlines()[-1])




def table(best: dict[str, dict[str, float]]) -> list[str]:
    lines = ["| preset | raw mj_step [steps/s] | env.step [physics steps/s] | ratio | env.step, no route-2 | ratio "
             "| real-time factor | bound: mj_step alone |", "|---|---|---|---|---|---|---|---|"]
    for scale, b in best.items():
        lines.append(f"| {scale} | {b['raw']:,.0f} | {b['env']:,.0f} | {b['env'] / b['raw']:.2f} | {b['fast']:,.0f} | "
                     f"{b['fast'] / b['raw']:.2f} | {b['rtf']:.1f} | {b['raw'] * b['timestep']:.1f} |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--baseline", type=Path, default=None, help="another checkout's root, measured side by side")
    ap.add_argument("--baseline-label", default="baseline")
    ap.add_argument("--out", default="benchmarks/results/env_throughput.md")
    args = ap.parse_args()
    import mujoco

    from scaletwin_envs.host import git_revision, host_line

    trees = {"this tree": ROOT}
    if args.baseline is not None:
        trees[args.baseline_label] = args.baseline.resolve()
    load_before = os.getloadavg()
    started = dt.datetime.now(dt.UTC)
    best = {label: {s: dict.fromkeys(("env", "fast", "raw", "rtf", "timestep"), 0.0) for s in SCALES}
            for label in trees}
    for _ in range(args.repeats):
        for scale in SCALES:
            for label, tree in trees.items():  # each tree in turn: both see the same load
                r = measure_in_subprocess(tree, scale)
                b = best[label][scale]
                for key in ("env", "fast", "raw", "rtf"):
                    b[key] = max(b[key], r[key])
                b["timestep"] = r["timestep"]
    load_after = os.getloadavg()
    minutes = (dt.datetime.now(dt.UTC) - started).total_seconds() / 60
    lines = [f"# env_throughput ({started:%Y-%m-%d %H:%M} UTC, {host_line()}, python {platform.python_version()}, "
             f"mujoco {mujoco.__version__}, git {git_revision()})", "",
             f"Load average (1/5/15 min) {load_before[0]:.2f}/{load_before[1]:.2f}/{load_before[2]:.2f} before, "
             f"{load_after[0]:.2f}/{load_after[1]:.2f}/{load_after[2]:.2f} after; {args.repeats} repeats, best of "
             f"each, {minutes:.1f} min. Ratios are env.step over raw mj_step measured in the same process.", ""]
    for label, per_scale in best.items():
        if len(trees) > 1:
            lines += [f"## {label}" + (f" ({trees[label]})" if label != "this tree" else ""), ""]
        lines += [*table(per_scale), ""]
    text = "\n".join(lines) + "\n"
    print(text)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
