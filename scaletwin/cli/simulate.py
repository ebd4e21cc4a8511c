"""``scaletwin simulate``: one standard dig cycle at a chosen scale; prints KPIs and peak signals.

``--parquet FILE`` records the episode (:mod:`scaletwin_envs.recording`), ``--rrd FILE`` logs it for the rerun
viewer (``scaletwin view FILE``); both are written atomically while the episode runs. Under the table, a line says
what ``success`` means and why this episode has it or not (:func:`success_line`).
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

from scaletwin.cli.common import add_machine_args, check_law

if TYPE_CHECKING:
    import gymnasium as gym


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="run one dig cycle and print its KPIs and peak signals")
    add_machine_args(p)
    p.add_argument("--json", metavar="FILE", help="also write KPIs and peaks as JSON")
    p.add_argument("--parquet", metavar="FILE", help="also record the episode as Parquet (SI, units, provenance)")
    p.add_argument("--rrd", metavar="FILE", help="also log the episode for rerun (.rrd; open with scaletwin view)")
    p.set_defaults(func=run)


@contextlib.contextmanager
def _recorders(args: argparse.Namespace, env: gym.Env, policy: Any) -> Iterator[Callable[..., None] | None]:
    """An on_step callback feeding the requested outputs; files are written when the block exits cleanly."""
    if not (args.rrd or args.parquet):
        yield None
        return
    from scaletwin_envs.recording.recorder import describe_policy

    callbacks: list[Callable[..., None]] = []
    with contextlib.ExitStack() as stack:
        if args.rrd:
            from scaletwin_envs.recording.atomic import atomic_path
            from scaletwin_envs.recording.rerun_log import RerunLogger, open_stream

            rec = open_stream(stack.enter_context(atomic_path(args.rrd)), name=f"{args.scale} seed {args.seed}")
            logger = RerunLogger(env, rec, seed=args.seed, policy=describe_policy(policy))
            stack.callback(rec.disconnect)
            stack.callback(logger.close)
            callbacks.append(logger)
        recorder = None
        if args.parquet:
            from scaletwin_envs.recording.recorder import EpisodeRecorder

            recorder = EpisodeRecorder(env, args.seed, describe_policy(policy))
            callbacks.append(recorder)

        def on_step(step: int, action: Any, info: dict[str, Any]) -> None:
            for cb in callbacks:
                cb(step, action, info)

        yield on_step
        if recorder is not None:
            recorder.recording().to_parquet(args.parquet)


def success_line(kpis: dict[str, Any], success_fill: float, time_limit: float) -> str:
    """``success`` explained: the criteria (the env's ``success_fill`` and time limit, in s) and which of them this
    episode met or missed."""
    if kpis["success"]:
        verdict = f"success True: the cycle completed with fill factor {kpis['fill_factor']:.3g} >= {success_fill:g}"
    else:
        missed = []
        if kpis["sim_error"]:
            missed.append(f"the simulation failed ({kpis['sim_error']})")
        elif kpis["cycle_time"] >= time_limit:
            missed.append(f"the cycle did not complete within the time limit of {time_limit:.3g} s")
        if kpis["fill_factor"] < success_fill:
            missed.append(f"fill factor {kpis['fill_factor']:.3g} < {success_fill:g}")
        verdict = "success False: " + " and ".join(missed or ["the cycle did not complete"])
    return (f"{verdict}. A dig succeeds when its cycle completes (bucket lifted clear of the pile, machine pulled "
            f"back) within the time limit ({time_limit:.3g} s here) with a fill factor (load / heaped bucket "
            f"volume) of at least {success_fill:g}.")


def run(args: argparse.Namespace) -> int:
    check_law([args.scale], args.law, "--scale")
    import gymnasium as gym
    from rich.console import Console
    from rich.table import Table

    import scaletwin_envs
    from scaletwin_envs.policies import ScriptedDigPolicy
    from scaletwin_envs.rollout import run_episode

    env = gym.make(scaletwin_envs.ENV_ID, scale=args.scale, law=args.law, soil=args.soil)
    policy = ScriptedDigPolicy()
    with _recorders(args, env, policy) as on_step:
        episode = run_episode(env, policy, seed=args.seed, on_step=on_step)
    kpis, peaks = episode.kpis.to_dict(), episode.peaks()
    loader = env.unwrapped.loader
    console = Console()
    table = Table(title=f"{loader.name}: {loader.operating_mass:,.1f} kg, soil {args.soil}, seed {args.seed}")
    table.add_column("KPI")
    table.add_column("value", justify="right")
    units = {"loaded_mass": "kg", "cycle_time": "s", "hydraulic_work": "J", "specific_energy": "J/kg",
             "spilled_mass": "kg"}
    for k, v in kpis.items():
        table.add_row(k, f"{v:.4g} {units.get(k, '')}".strip() if isinstance(v, float) else str(v))
    for k, v in peaks.items():
        unit = {"a1": "m/s^2", "alpha1": "rad/s^2"}.get(k, "N")
        table.add_row(f"peak {k}", f"{v:.4g} {unit}")
    console.print(table)
    unwrapped = env.unwrapped
    console.print(success_line(kpis, unwrapped.success_fill,
                               unwrapped.max_episode_time * unwrapped.loader.froude_time), markup=False,
                  highlight=False)
    if args.json:
        from scaling.runs.provenance import write_json

        write_json(args.json, {"loader": loader.to_dict(), "soil": args.soil, "seed": args.seed, "kpis": kpis,
                               "peaks": peaks})
    for kind, path in (("recording", args.parquet), ("rerun log", args.rrd)):
        if path:
            console.print(f"{kind}: {path}")
    return 1 if kpis["sim_error"] else 0
