"""``scaletwin zoo list`` and ``scaletwin zoo show NAME``: the registered checkpoints and their cards."""

from __future__ import annotations

import argparse
import json

from rich.console import Console
from rich.table import Table

from scaletwin.cli import CommandError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("zoo", help="list the zoo's checkpoints or show one's card")
    zsub = p.add_subparsers(dest="zoo_command", metavar="{list,show}", required=True)
    ls = zsub.add_parser("list", help="registered checkpoints")
    ls.add_argument("--kind", help="only this kind (policy, scaling-model)")
    ls.set_defaults(func=run_list)
    show = zsub.add_parser("show", help="a checkpoint's card (name or directory)")
    show.add_argument("name")
    show.add_argument("--verify", action="store_true", help="also verify every file's sha256 and rebuild it")
    show.add_argument("--json", action="store_true", help="print the whole card as JSON")
    show.set_defaults(func=run_show)


def run_list(args: argparse.Namespace) -> int:
    import zoo
    from zoo.registry import read_registry

    table = Table(title="zoo")
    for col in ("name", "kind", "summary"):
        table.add_column(col)
    entries = read_registry()
    for name in zoo.list(kind=args.kind):
        table.add_row(name, entries[name]["kind"], entries[name].get("summary", ""))
    Console().print(table)
    return 0


def run_show(args: argparse.Namespace) -> int:
    import zoo

    try:
        card = zoo.card(args.name)
        if args.verify:
            zoo.load(args.name)
    except zoo.CheckpointError as exc:
        raise CommandError(str(exc)) from exc
    console = Console()
    if args.json:
        console.print_json(json.dumps(card))
        return 0
    table = Table(title=f"{card['name']} ({card['kind']})" + (": verified" if args.verify else ""))
    table.add_column("field")
    table.add_column("value", overflow="fold")
    for key in ("description", "algorithm", "env_id", "env_kwargs", "policy_kwargs", "seed", "created", "versions",
                "files"):
        if key in card:
            value = card[key]
            table.add_row(key, value if isinstance(value, str) else json.dumps(value))
    training = card.get("training", {})
    for key in ("method", "wall_time", "machine"):
        if key in training:
            table.add_row(f"training.{key}", json.dumps(training[key]) if not isinstance(training[key], str)
                          else training[key])
    console.print(table)
    return 0
