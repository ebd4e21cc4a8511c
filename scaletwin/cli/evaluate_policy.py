"""``scaletwin evaluate-policy``: KPIs of learned, scripted and random dig policies over seeded episodes.

Prints the summary table and writes ``policy_kpis.md``, ``policy_kpis.csv`` (summary),
``policy_kpis_episodes.csv`` (one row per episode) and ``policy_kpis.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from scaletwin.cli import CommandError
from scaletwin.cli.common import add_executor_args, executor_from_args, scale_arg

if TYPE_CHECKING:
    from rich.console import Console

DEFAULT_MODEL = "bucketfill-ppo"
#: Compact headings for the terminal (the Markdown table spells them out).
SHORT_HEADS = ("policy", "scale", "soil", "fill", "mass kg", "cycle s", "cycle √(L/g)", "work J", "J/kg", "spill kg",
               "success", "errors", "n")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate-policy", help="compare dig policies' KPIs over scales and soils")
    p.add_argument("--policies", default="learned,scripted,random",
                   help="comma list: learned (the --model checkpoint), scripted, scripted-tuned, random, or any "
                        "zoo checkpoint name or path (default learned,scripted,random)")
    p.add_argument("--model", default=DEFAULT_MODEL, help=f"zoo checkpoint used as 'learned' (default {DEFAULT_MODEL})")
    p.add_argument("--scales",
                   help="comma list of presets and length ratios (default mini,er12,wa475,0.3,1.5)")
    p.add_argument("--soils", help="comma list (default gravel,clay_loam)")
    p.add_argument("--episodes", type=int, default=5, help="seeded episodes per policy, scale and soil (default 5)")
    p.add_argument("--seed", type=int, default=0, help="first episode seed (default 0)")
    p.add_argument("--workers", default=None,
                   help="local worker processes (default: all cores; 1 or 'serial' runs in this process)")
    add_executor_args(p)
    p.add_argument("--out", type=Path, default=Path("policy_kpis"), help="output directory (default ./policy_kpis)")
    p.set_defaults(func=run)


def resolve_policy(name: str, model: str) -> Any:
    """A policy object for a name on the command line (zoo names are loaded with their hashes verified)."""
    from scaletwin_envs.policies import TUNED, RandomPolicy, ScriptedDigPolicy

    if name == "scripted":
        return ScriptedDigPolicy()
    if name == "scripted-tuned":
        return ScriptedDigPolicy(**TUNED)
    if name == "random":
        return RandomPolicy()
    import zoo

    try:
        return zoo.load(model if name == "learned" else name)
    except zoo.CheckpointError as exc:
        raise CommandError(str(exc)) from exc


def describe(name: str, policy: Any) -> str:
    """One line for the report's legend."""
    text = {"scripted": "ScriptedDigPolicy() (default parameters)", "random": "uniform random commands",
            "scripted-tuned": "ScriptedDigPolicy(**TUNED), the learned policy's teacher"}.get(name)
    if text is None:
        card = getattr(policy, "card", {})
        text = f"zoo checkpoint `{card.get('name', name)}` ({card.get('algorithm', '?')})"
    return f"`{name}`: {text}"


def _split(text: str) -> list[str]:
    items = [t.strip() for t in text.split(",") if t.strip()]
    if not items:
        raise CommandError(f"empty list: {text!r}")
    return items




def print_table(summary: Any, console: Console) -> None:
    from rich.table import Table

    from scaletwin_envs.evaluation import summary_rows

    _, rows = summary_rows(summary)
    table = Table(title="Policy KPIs (deterministic, mean over episodes)")
    for i, h in enumerate(SHORT_HEADS):
        table.add_column(h, justify="left" if i < 3 else "right", no_wrap=i < 3)
    for r in rows:
        table.add_row(*r)
    console.print(table)


def run(args: argparse.Namespace) -> int:
    executor = executor_from_args(args, args.workers)  # before the heavy imports: bad options fail at once
    from rich.console import Console

    from scaletwin_envs.evaluation import (
        DEFAULT_SCALES,
        DEFAULT_SOILS,
        evaluate_policies,
        plot_kpis,
        summarize,
        write_csv,
        write_markdown,
    )

    if args.episodes < 1:
        raise CommandError("--episodes must be >= 1")
    policies = {name: resolve_policy(name, args.model) for name in _split(args.policies)}
    scales = list(DEFAULT_SCALES) if args.scales is None else [scale_arg(s) for s in _split(args.scales)]
    soils = list(DEFAULT_SOILS) if args.soils is None else _split(args.soils)
    episodes = evaluate_policies(policies, scales, soils, args.episodes, args.seed, executor=executor)
    summary = summarize(episodes)
    console = Console() if sys.stdout.isatty() else Console(width=200)  # pipes and logs get the whole table
    print_table(summary, console)
    out = Path(args.out)
    seeds = f"seeds {args.seed}..{args.seed + args.episodes - 1}"
    legend = "; ".join(describe(n, p) for n, p in policies.items())
    notes = (f"Policies: {legend}.\n\nEpisodes per policy, scale and soil: {args.episodes} ({seeds}); "
             "deterministic policies; means over episodes; specific energy = hydraulic work / loaded mass.")
    written = [write_markdown(summary, out / "policy_kpis.md", notes=notes),
               write_csv(summary, out / "policy_kpis.csv"), write_csv(episodes, out / "policy_kpis_episodes.csv"),
               plot_kpis(summary, out / "policy_kpis.png")]
    console.print("wrote " + ", ".join(str(p) for p in written))
    return 1 if int(summary["sim_errors"].sum()) else 0
