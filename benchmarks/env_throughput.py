"""Physics throughput of WheelLoaderDig-v1: raw ``mj_step`` on the env's own model vs ``env.step``, side by side.

**Ratio.** Every control step of a scripted dig is timed three ways, one right after the other: ``env.step`` of an
env without the second route to the pin forces (what ``gym.make`` gives when nothing records the episode),
``env.step`` of a twin env with it (``two_route_check=True``: what a recording costs), and raw ``mj_step`` of the
same number of physics steps from the same state (the env's full integration state before its step, set on a
separate ``MjData`` of the same model: load, soil dampers and controls as the env had them; no soil update,
signals or Python in between). The twin gets the same commands: route 2 is a passive check, so both envs follow
the same trajectory bit for bit (checked). The episode is repeated and each step keeps its fastest time over the
repeats (the same work every time; a busy machine only ever slows a step down), so the three columns see the
same load at the scale of a millisecond, which the 2 shared cores this runs on need.

**Real-time factor.** Simulated seconds per wall second of the scripted dig: its reset, policy calls and
``env.step`` calls, each at its fastest over the repeats (for the env as ``gym.make`` gives it, and with route 2);
and of one whole dig timed end to end (``rollout.run_episode``), fastest repeat, which the machine's load slows
down as a whole. The bound is ``mj_step`` alone (timestep × raw steps per second).

**Timestep convergence.** Whether the default physics timestep (the Froude step 1 ms × √λ divided into
``scaletwin_envs.builder.timestep_substeps`` parts: 1 at every machine with the constraint servo,
``scaletwin_envs.builder.SERVO_KINDS``; the legacy actuator servo divided the mini's into 3), which bounds the
real-time factor, is converged: F21 of the scripted dig at the timestep × 1/2 and × 2 (``gym.make(...,
timestep=...)``: control step, soil refresh period and constraint time constant unchanged in seconds), the default
run's commands replayed open loop, against the default run; mean absolute percentage difference over the dig rows
(penetrate, curl, lift). A timestep may be called a numerical choice only where it moves F21 by < 1 %
(``tests/envs/test_env_speed.py``).

**Servo sweep** (``--servo-sweep``, about 3 min per tree): for 26 machines (the presets, the product-line law at
λ 0.1-2.5, the Froude law at 1/7, design-space samples) the scripted dig is run at the Froude step and its commands
replayed at the Froude step / n; each n's F21 over the dig rows is scored against n's half step (2n), and the pairs
are binned by the timestep's ratio to the tilt servo's time constant (the ratio at which the legacy actuator servo
relayed at relief). With ``--baseline`` the sweep runs in both trees and a side-by-side table compares each tree's
default step.

``--baseline DIR`` also measures another checkout of ``scaletwin_envs`` (e.g. ``git archive REV scaletwin_envs |
tar -x -C DIR``) in the same run: every repeat measures each tree in turn, in fresh processes.

Run: ``python benchmarks/env_throughput.py [--repeats N] [--baseline DIR] [--servo-sweep] [--out FILE]`` (default FILE:
``benchmarks/results/env_throughput.md``).
"""

from __future__ import annotations

import argparse
import datetime as dt
import itertools
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCALES = ("mini", "er12", "wa475")
DIG_PHASES = ("penetrate", "curl", "lift")  # rows over which the timestep convergence is scored
TIMESTEP_FACTORS = (0.5, 2.0)
SWEEP_PARTS = (1, 2, 3, 4, 6, 8)  # Froude step / n scored against / 2n
SWEEP_BINS = (0.0, 10.0, 20.0, 30.0, float("inf"))  # timestep / tilt-servo time constant


def measure(scale: str, repeats: int) -> dict[str, float]:
    """Every rate at ``scale`` in this process (imports the scaletwin_envs first on sys.path)."""
    import gymnasium as gym
    import mujoco
    import numpy as np

    import scaletwin_envs
    from scaletwin_envs.policies import ScriptedDigPolicy
    from scaletwin_envs.rollout import run_episode

    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    best: list[list[float]] | None = None
    n_steps = 0
    for rep in range(repeats):
        fast = gym.make(scaletwin_envs.ENV_ID, scale=scale, two_route_check=False)
        full = gym.make(scaletwin_envs.ENV_ID, scale=scale, two_route_check=True)
        u = fast.unwrapped
        model, raw = u.model, mujoco.MjData(u.model)
        state = np.empty(mujoco.mj_stateSize(model, spec))
        policy = ScriptedDigPolicy()
        start = time.perf_counter()
        obs, _ = fast.reset(seed=0)
        reset = time.perf_counter() - start
        obs_full, _ = full.reset(seed=0)
        times: list[list[float]] = [[0.0, 0.0, 0.0, reset]]  # row 0: the reset (of the route-1 env)
        done = False
        while not done:
            start = time.perf_counter()
            action = policy.act(obs)
            t: list[float] = [0.0, 0.0, 0.0, time.perf_counter() - start]  # fast, full, raw, policy
            mujoco.mj_getState(model, u.data, state, spec)
            for k in ((0, 1, 2), (1, 2, 0), (2, 0, 1))[len(times) % 3]:  # rotate the order step by step
                start = time.perf_counter()
                if k == 0:
                    obs, _, term, trunc, _ = fast.step(action)
                elif k == 1:
                    obs_full, *_ = full.step(action)
                else:
                    mujoco.mj_setState(model, raw, state, spec)
                    start = time.perf_counter()
                    mujoco.mj_step(model, raw, u.frame_skip)
                t[k] = time.perf_counter() - start
            if not np.array_equal(obs, obs_full):
                raise RuntimeError(f"{scale}: route 2 changed the trajectory at step {len(times)}")
            times.append(t)
            done = term or trunc
        if best is None:
            best, n_steps = times, len(times)
        elif len(times) != n_steps:
            raise RuntimeError(f"{scale}: repeat {rep} ran {len(times)} steps, the first {n_steps}")
        else:
            best = [[min(a, b) for a, b in zip(x, y, strict=True)] for x, y in zip(best, times, strict=True)]
    assert best is not None
    t_fast, t_full, t_raw, t_other = (sum(row[k] for row in best) for k in range(4))  # t_other: reset + policy
    physics_steps = (n_steps - 1) * fast.unwrapped.frame_skip
    timestep = float(model.opt.timestep)
    simulated = physics_steps * timestep

    def rtf(two_routes: bool) -> float:
        """Real-time factor of the fastest of ``repeats`` whole scripted digs."""
        env = gym.make(scaletwin_envs.ENV_ID, scale=scale, two_route_check=two_routes)
        fastest, sim = float("inf"), 0.0
        for _ in range(repeats):
            start = time.perf_counter()
            ep = run_episode(env, ScriptedDigPolicy(), seed=0)
            fastest = min(fastest, time.perf_counter() - start)
            sim = ep.infos[-1]["time"]
        return sim / fastest

    return {"raw": physics_steps / t_raw, "fast": physics_steps / t_fast, "full": physics_steps / t_full,
            "rtf_fast": simulated / (t_fast + t_other), "rtf_full": simulated / (t_full + t_other),
            "rtf_whole": rtf(False), "timestep": timestep, "steps": n_steps - 1}


def _env_at(scale: str, factor: float):  # -> gymnasium.Env (gymnasium is imported lazily)
    """The dig env with the physics timestep × ``factor`` (its ``timestep`` keyword: frame_skip and the soil refresh
    count follow, so the control step and the soil refresh period stay the same in seconds)."""
    import gymnasium as gym

    import scaletwin_envs
    from scaletwin_envs.builder import BuildOptions
    from scaletwin_envs.specs import make_loader

    return gym.make(scaletwin_envs.ENV_ID, scale=scale,
                    timestep=factor * BuildOptions.for_spec(make_loader(scale)).timestep)


def convergence(scale: str) -> dict[str, float]:
    """F21 MAPE (%) and median relative difference (%) over the dig rows at each of :data:`TIMESTEP_FACTORS`
    against the default timestep, commands replayed open loop; the default's substeps and its tilt-servo ratio."""
    import numpy as np

    from scaletwin_envs.builder import froude_timestep, servo_time_constant, timestep_substeps
    from scaletwin_envs.policies import ScriptedDigPolicy
    from scaletwin_envs.rollout import run_episode
    from scaletwin_envs.specs import make_loader

    spec = make_loader(scale)
    n = timestep_substeps(spec)
    ref = run_episode(_env_at(scale, 1.0), ScriptedDigPolicy(), seed=0)
    rows = [k for k, info in enumerate(ref.infos) if info["phase"] in DIG_PHASES]
    f21 = ref.signal("F21")[rows]
    out: dict[str, float] = {"peak_F21": float(np.abs(f21).max()), "substeps": float(n),
                             "servo_ratio": froude_timestep(spec) / n / servo_time_constant(spec, "tilt")}
    for factor in TIMESTEP_FACTORS:
        env = _env_at(scale, factor)
        env.reset(seed=0)
        other = np.array([env.step(a)[4]["signals"]["F21"] for a in ref.actions])[rows]
        rel = np.abs(other - f21) / np.abs(f21)
        out[f"mape_{factor}"] = float(rel.mean() * 100)
        out[f"median_{factor}"] = float(np.median(rel) * 100)
    return out


def sweep_machines() -> list[tuple[str, object]]:
    """The sweep's machines: (name, LoaderSpec)."""
    from scaletwin_envs.design_space import DesignSpace
    from scaletwin_envs.specs import make_loader

    out: list[tuple[str, object]] = [(p, make_loader(p)) for p in SCALES]
    out += [(f"product line λ {lam:g}", make_loader(lam)) for lam in (0.1, 0.143, 0.2, 0.3, 0.5, 0.75, 1.5, 2.5)]
    out.append(("Froude law λ 1/7", make_loader(1 / 7, "froude")))
    out += [(f"pl0-{i}", DesignSpace().sample_one(0, i).spec) for i in range(8)]
    out += [(f"pl1-{i} (λ 0.08-0.4)", DesignSpace(scale=(0.08, 0.4)).sample_one(1, i).spec) for i in range(6)]
    return out


def n_sweep_machines() -> int:
    return len(sweep_machines())


def servo_sweep(index: int) -> dict[str, object]:
    """Machine ``index`` of :func:`sweep_machines`: its tilt-servo ratio at the Froude step, the rule's parts, and the
    F21 MAPE (%) over the dig rows of the Froude step / n against / 2n for n in :data:`SWEEP_PARTS` (the Froude run's
    commands replayed open loop)."""
    import gymnasium as gym
    import numpy as np

    import scaletwin_envs
    from scaletwin_envs.builder import froude_timestep, servo_time_constant, timestep_substeps
    from scaletwin_envs.policies import ScriptedDigPolicy
    from scaletwin_envs.rollout import run_episode

    name, spec = sweep_machines()[index]
    froude = froude_timestep(spec)

    def env(parts: int):  # -> gymnasium.Env
        return gym.make(scaletwin_envs.ENV_ID, scale=spec, timestep=froude / parts)

    ref = run_episode(env(1), ScriptedDigPolicy(), seed=0)
    rows = [k for k, info in enumerate(ref.infos) if info["phase"] in DIG_PHASES]
    f21: dict[int, np.ndarray] = {}
    for parts in sorted({n for n in SWEEP_PARTS} | {2 * n for n in SWEEP_PARTS}):
        e = env(parts)
        e.reset(seed=0)
        f21[parts] = np.array([e.step(a)[4]["signals"]["F21"] for a in ref.actions])[rows]
    return {"name": name, "scale": spec.scale, "ratio": froude / servo_time_constant(spec, "tilt"),
            "rule": timestep_substeps(spec),
            "mape": {n: float(np.mean(np.abs(f21[2 * n] - f21[n]) / np.abs(f21[n])) * 100) for n in SWEEP_PARTS}}


def sweep_table(sweep: list[dict]) -> list[str]:
    lines = ["| machine | λ | Froude step / tilt-servo τ | rule's parts | "
             + " | ".join(f"F21 MAPE, step / {n} vs / {2 * n}" for n in SWEEP_PARTS) + " |",
             "|---|---|---|---|" + "---|" * len(SWEEP_PARTS)]
    for s in sweep:
        cells = [f"**{s['mape'][n]:.2f} %**" if n == s["rule"] else f"{s['mape'][n]:.2f} %" for n in SWEEP_PARTS]
        lines.append(f"| {s['name']} | {s['scale']:.3f} | {s['ratio']:.1f} | {s['rule']} | " + " | ".join(cells) + " |")
    lines += ["", "| timestep / tilt-servo τ | (machine, step) pairs | halving moves F21 by < 1 % |", "|---|---|---|"]
    for lo, hi in itertools.pairwise(SWEEP_BINS):
        pairs = [s["mape"][n] < 1.0 for s in sweep for n in SWEEP_PARTS if lo <= s["ratio"] / n < hi]
        if pairs:
            lines.append(f"| {lo:g}-{hi:g} | {len(pairs)} | {sum(pairs)} ({100 * sum(pairs) / len(pairs):.0f} %) |")
    ruled = [s["mape"][s["rule"]] < 1.0 for s in sweep if s["rule"] in SWEEP_PARTS]
    lines += ["", f"At the rule's step (bold): {sum(ruled)} of {len(ruled)} machines converged."]
    return lines


def side_by_side(sweeps: dict[str, list[dict]]) -> list[str]:
    labels = list(sweeps)
    lines = ["| machine | λ | Froude step / tilt-servo τ | " + " | ".join(
        f"{lb}: parts | {lb}: F21 MAPE, step vs step / 2" for lb in labels) + " |",
        "|---|---|---|" + "---|---|" * len(labels)]
    for rows in zip(*sweeps.values(), strict=True):
        s0 = rows[0]
        cells = [f"{s['rule']} | {s['mape'][s['rule']]:.2f} %" if s["rule"] in s["mape"] else f"{s['rule']} | -"
                 for s in rows]
        lines.append(f"| {s0['name']} | {s0['scale']:.3f} | {s0['ratio']:.1f} | " + " | ".join(cells) + " |")
    counts = [sum(s["mape"].get(s["rule"], 99.0) < 1.0 for s in sweeps[lb]) for lb in labels]
    lines += ["", "Converged at the default step: " + ", ".join(
        f"{lb} {c} of {len(sweeps[lb])}" for lb, c in zip(labels, counts, strict=True)) + "."]
    return lines


def in_subprocess(tree: Path, call: str) -> dict[str, float]:
    """``env_throughput.<call>`` in a fresh interpreter with ``tree`` first on sys.path (its scaletwin_envs)."""
    code = (f"import sys, json; sys.path.insert(0, {str(tree)!r}); sys.path.insert(1, {str(ROOT / 'benchmarks')!r}); "
            f"import scaletwin_envs; assert scaletwin_envs.__file__.startswith({str(tree)!r}), "
            f"scaletwin_envs.__file__; import env_throughput; print(json.dumps(env_throughput.{call}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=tree)
    return json.loads(out.stdout.strip().splitlines()[-1])


def table(results: dict[str, dict[str, float]]) -> list[str]:
    lines = ["| preset | timestep [ms] | raw mj_step [steps/s] | env.step [physics steps/s] | ratio | env.step with "
             "route 2 | ratio | real-time factor | with route 2 | whole dig, fastest repeat | bound: mj_step alone |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for scale, b in results.items():
        lines.append(f"| {scale} | {b['timestep'] * 1e3:.3f} | {b['raw']:,.0f} | {b['fast']:,.0f} | "
                     f"{b['fast'] / b['raw']:.2f} | {b['full']:,.0f} | {b['full'] / b['raw']:.2f} | "
                     f"{b['rtf_fast']:.0f} | {b['rtf_full']:.0f} | {b['rtf_whole']:.0f} | "
                     f"{b['raw'] * b['timestep']:.0f} |")
    return lines


def convergence_table(conv: dict[str, dict[str, float]]) -> list[str]:
    lines = ["| preset | Froude step / timestep | timestep / tilt-servo τ | peak F21 [N] | F21 MAPE, timestep × 1/2 | "
             "median | F21 MAPE, timestep × 2 | median |",
             "|---|---|---|---|---|---|---|---|"]
    for scale, c in conv.items():
        lines.append(f"| {scale} | {c['substeps']:.0f} | {c['servo_ratio']:.1f} | {c['peak_F21']:,.0f} | "
                     f"{c['mape_0.5']:.2f} % | {c['median_0.5']:.2f} % | {c['mape_2.0']:.2f} % | "
                     f"{c['median_2.0']:.2f} % |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=10, help="episodes per measurement (fastest kept)")
    ap.add_argument("--baseline", type=Path, default=None, help="another checkout's root, measured side by side")
    ap.add_argument("--baseline-label", default="baseline")
    ap.add_argument("--servo-sweep", action="store_true", help="also run the timestep sweep over 26 machines")
    ap.add_argument("--out", default="benchmarks/results/env_throughput.md")
    args = ap.parse_args()
    import mujoco

    from scaletwin_envs.host import git_revision, host_line

    trees = {"this tree": ROOT}
    if args.baseline is not None:
        trees[args.baseline_label] = args.baseline.resolve()
    load_before = os.getloadavg()
    started = dt.datetime.now(dt.UTC)
    results: dict[str, dict[str, dict[str, float]]] = {label: {} for label in trees}
    for scale in SCALES:
        for label, tree in trees.items():  # each tree in turn: both see the same load
            results[label][scale] = in_subprocess(tree, f"measure({scale!r}, {args.repeats})")
    conv = {scale: in_subprocess(ROOT, f"convergence({scale!r})") for scale in SCALES}
    sweeps: dict[str, list[dict]] = {}
    if args.servo_sweep:
        n_machines = int(in_subprocess(ROOT, "n_sweep_machines()"))
        for label, tree in trees.items():
            sweeps[label] = [in_subprocess(tree, f"servo_sweep({k})") for k in range(n_machines)]
            for s in sweeps[label]:
                s["mape"] = {int(n): v for n, v in s["mape"].items()}  # JSON keys are strings
    load_after = os.getloadavg()
    minutes = (dt.datetime.now(dt.UTC) - started).total_seconds() / 60
    lines = [f"# env_throughput ({started:%Y-%m-%d %H:%M} UTC, {host_line()}, python {platform.python_version()}, "
             f"mujoco {mujoco.__version__}, git {git_revision()})", "",
             f"Load average (1/5/15 min) {load_before[0]:.2f}/{load_before[1]:.2f}/{load_before[2]:.2f} before, "
             f"{load_after[0]:.2f}/{load_after[1]:.2f}/{load_after[2]:.2f} after; {args.repeats} repeats, "
             f"{minutes:.1f} min. Per control step, env.step (route 1 only, as `gym.make` gives it unless a recorder "
             "watches), env.step with route 2 (`two_route_check=True`, what a recording costs) and raw mj_step of "
             "the same physics steps from the same state run back to back; each step keeps its fastest time over "
             "the repeats. Real-time factor: simulated time of the scripted dig over its reset, policy and env.step "
             "times (each at its fastest); also measured as one whole dig (`rollout.run_episode`, fastest repeat), "
             "which a loaded machine slows down.", ""]
    for label, per_scale in results.items():
        if len(trees) > 1:
            lines += [f"## {label}" + (f" ({trees[label]})" if label != "this tree" else ""), ""]
        lines += [*table(per_scale), ""]
    lines += ["## Timestep convergence (this tree)", "",
              "F21 of the scripted dig at the physics timestep × 1/2 and × 2 (control step, soil refresh and "
              "constraint time constant unchanged in seconds; the default run's commands replayed open loop) against "
              "the default timestep (the Froude step 1 ms × √λ over `builder.timestep_substeps`: 1 with the "
              "constraint servo, `builder.SERVO_KINDS`), over the dig rows (penetrate, curl, lift). A timestep is "
              "converged where halving it moves F21 by < 1 %; a larger one would be a numerical choice only if it "
              "moved F21 by < 1 % too.", "", *convergence_table(conv), ""]
    if len(sweeps) > 1:
        lines += ["## Default timestep, side by side", "",
                  "Each tree's default step (its `builder.timestep_substeps` parts of the Froude step) and the F21 "
                  "MAPE over the dig rows of that step against its half (< 1 %: converged).", "",
                  *side_by_side(sweeps), ""]
    for label, sweep in sweeps.items():
        lines += [f"## Timestep against the tilt servo's time constant ({label})", "",
                  "Each machine's scripted dig at its Froude step, the commands replayed at the Froude step / n and "
                  "/ 2n; F21 MAPE over the dig rows of n against 2n. τ: the tilt slide's inertia (armature + rod) "
                  "over its velocity servo's gain (`builder.servo_time_constant`). The rule's parts: "
                  "`builder.timestep_substeps` (bold: that step).", "", *sweep_table(sweep), ""]
    text = "\n".join(lines) + "\n"
    print(text)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
