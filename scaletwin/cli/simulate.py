"""``scaletwin simulate``: one standard dig cycle at a chosen scale; prints KPIs and peak signals."""

from __future__ import annotations

import argparse

import gymnasium as gym
from rich.console import Console
from rich.table import Table

import scaletwin_envs
from scaletwin.cli.common import add_machine_args, write_json
from scaletwin_envs.policies import ScriptedDigPolicy
from scaletwin_envs.rollout import run_episode


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="run one dig cycle and print its KPIs and peak signals")
    add_machine_args(p)
    p.add_argument("--json", metavar="FILE", help="also write KPIs and peaks as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    env = gym.make(scaletwin_envs.ENV_ID, scale=args.scale, law=args.law, soil=args.soil)
    episode = run_episode(env, ScriptedDigPolicy(), seed=args.seed)
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
    if args.json:
        write_json(args.json, {"loader": loader.to_dict(), "soil": args.soil, "seed": args.seed, "kpis": kpis,
                               "peaks": peaks})
    return 1 if kpis["sim_error"] else 0
