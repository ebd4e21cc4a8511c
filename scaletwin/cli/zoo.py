"""``scaletwin zoo list`` and ``scaletwin zoo show NAME``: the registered checkpoints and their cards."""

from __future__ import annotations

import argparse
import json
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

from scaletwin.cli import CommandError
from scaletwin.cli.common import add_executor_args, executor_from_args


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("zoo", help="list the zoo's checkpoints or show one's card")
    zsub = p.add_subparsers(dest="zoo_command", metavar="{list,show,build}", required=True)
    ls = zsub.add_parser("list", help="registered checkpoints")
    ls.add_argument("--kind", help="only this kind (policy, scaling-model)")
    ls.set_defaults(func=run_list)
    show = zsub.add_parser("show", help="a checkpoint's card (name or directory)")
    show.add_argument("name")
    show.add_argument("--verify", action="store_true", help="also verify every file's sha256 and rebuild it")
    show.add_argument("--json", action="store_true", help="print the whole card as JSON")
    show.set_defaults(func=run_show)
    build = zsub.add_parser("build", help="rebuild the δ1 checkpoints from scratch (data → fit → evaluate)")
    build.add_argument("--data", default=None,
                       help="recordings folder (train/, held_out/; with --product-line train/, test/); simulated "
                            "there if missing (default runs/zoo-data, runs/zoo-product-line)")
    build.add_argument("--product-line", action="store_true",
                       help="build the product-line checkpoints statics-pl and statics-pl-ens (zoo.product_line) "
                            "instead of the paper's")
    build.add_argument("--only", nargs="+", metavar="NAME", help="only these entries (default: all)")
    build.add_argument("--seed", type=int, default=0, help="pipeline seed (default 0)")
    build.add_argument("--out", help="checkpoint root (default: the package's zoo/checkpoints)")
    build.add_argument("--registry", help="registry file to update (default: the package's zoo/registry.json)")
    build.add_argument("--workers", default=None,
                       help="local simulation workers: an integer or 'serial' (default: all cores; 2 with "
                            "--product-line)")
    add_executor_args(build)
    build.set_defaults(func=run_build)


def _configured(cfg: Any, args: argparse.Namespace, executor: Any) -> Any:
    """A build config (:class:`zoo.build.BuildConfig` or :class:`zoo.product_line.ProductLineBuild`) with the
    options given: ``--out``, ``--registry`` and the executor (``None`` keeps the config's default)."""
    changes: dict[str, Any] = {} if executor is None else {"executor": executor}
    if args.out:
        changes["out_root"] = Path(args.out)
    if args.registry:
        changes["registry"] = Path(args.registry)
    return replace(cfg, **changes)


def _build_product_line(args: argparse.Namespace, executor: Any) -> int:
    from zoo.product_line import ENSEMBLE_NAME, NAME, ProductLineBuild, build_product_line, ensemble_build

    names = (NAME, ENSEMBLE_NAME)
    if args.only and (unknown := sorted(set(args.only) - set(names))):
        raise CommandError(f"--product-line builds {' and '.join(names)}; not {', '.join(unknown)}")
    common = {"data_dir": Path(args.data or "runs/zoo-product-line"), "seed": args.seed}
    builds = {NAME: ProductLineBuild(**common), ENSEMBLE_NAME: ensemble_build(**common)}
    import zoo

    for name in args.only or names:
        cfg = _configured(builds[name], args, executor)
        path = build_product_line(cfg)
        metrics = zoo.card(path, cfg.registry)["metrics"]
        print(f"{name}: {path}\n  held-out drawn machines: {summary_text(metrics['summary'])}")
        if "multi_source" in metrics:
            print(f"  from {metrics['multi_source']['sources']} sources: "
                  f"{summary_text(metrics['multi_source']['summary'])}")
    return 0


def run_list(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

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


def run_build(args: argparse.Namespace) -> int:
    executor = executor_from_args(args, args.workers)  # before the heavy imports: bad options fail at once
    import torch
    from rich.console import Console
    from rich.table import Table

    from zoo.build import BuildConfig, build_zoo

    torch.set_num_threads(1)
    if args.product_line:
        return _build_product_line(args, executor)
    cfg = _configured(BuildConfig(data_dir=Path(args.data or "runs/zoo-data"), seed=args.seed,
                                  names=tuple(args.only) if args.only else None), args, executor)
    built = build_zoo(cfg)
    table = Table(title="rebuilt checkpoints")
    for col in ("name", "directory", "held-out R² (dig)", "miniature error %"):
        table.add_column(col)
    import zoo

    for name, path in built.items():
        metrics = zoo.card(path)["metrics"]
        table.add_row(name, str(path), f"{metrics['held_out_episodes']['r2_dig']:.4f}",
                      f"{metrics['mini']['mean_abs_pct_error']:.2f}")
    Console().print(table)
    return 0


def summary_text(s: Mapping[str, Any]) -> str:
    """One line of a product-line card's held-out summary (``metrics["summary"]`` or its multi-source twin)."""
    return (f"{s['drawn_test_machines']} drawn: dig {s['dynamic_mape_pct_median']:.1f} % median, "
            f"{s['dynamic_mape_pct_worst']:.1f} % worst; hold {s['static_mape_pct_median']:.1f} / "
            f"{s['static_mape_pct_worst']:.1f} %; 90 % coverage {s['interval_coverage_min']:.2f}–"
            f"{s['interval_coverage_max']:.2f} ({s['interval_machines_85_95']} in 0.85–0.95)")


def risk_text(s: Mapping[str, Any]) -> str:
    """One line on a product-line card's served risk over its drawn held-out machines (or why it has none)."""
    if s.get("risk_unavailable"):
        return f"none: {s['risk_unavailable']}"
    at = s.get("risk_auroc_at") or {}
    auroc = " / ".join("–" if v is None else f"{v:.2f}" for v in (s.get("risk_auroc"), at.get("0.03"), at.get("0.05")))
    return (f"P(F21 > 10 % off), read off the interval; AUROC for rows > 10 / 3 / 5 % off {auroc}; warns on "
            f"{100 * s['risk_warned_share_median']:.1f} % of a machine's rows (median), "
            f"{100 * s['risk_warned_share_max']:.1f} % at most")


def scaling_rows(card: dict[str, Any]) -> list[tuple[str, str]]:
    """The headline fields of a scaling-model card as (field, text) rows (none for other kinds)."""
    if card.get("kind") != "scaling-model":
        return []
    groups, metrics, training = card["groups"], card["metrics"], card["training"]
    common = [("predicts", card["predicts"]["equation"]),
              ("groups", f"{groups['set']}: π1 = {groups['output']['expression']}; inputs "
                         + ", ".join(g["expression"] for g in groups["inputs"])),
              ("inputs", ", ".join(f"{d['name']} [{d['unit']}]" for d in card["inputs"])),
              ("interval", f"{card['interval']['method']} at {card['interval']['coverage']:.0%}")]
    if "held_out_episodes" not in metrics:  # a product-line card (zoo.product_line)
        s = metrics["summary"]
        machines = "; ".join(f"{m}: F21 MAPE dig {v['dynamic_mape_pct']:.1f} % / hold {v['static_mape_pct']:.1f} % "
                             f"(direct-Pi {v['direct_pi_dynamic_mape_pct']:.0f} / {v['direct_pi_static_mape_pct']:.0f}"
                             f" %), coverage {v['interval_coverage']:.2f}"
                             for m, v in metrics["held_out_machines"].items())
        return [*common,
                ("held_out machines", summary_text(s)),
                ("risk", risk_text(s)),
                ("per machine", machines),
                *([(f"from {metrics['multi_source']['sources']} sources",
                    f"scale_force_sources: {summary_text(metrics['multi_source']['summary'])}")]
                  if "multi_source" in metrics else []),
                ("training", f"{len(training['machines'])} machines, calibration on "
                             f"{len(training['calibration_machines'])}, data {training['data_hash']}, seed "
                             f"{training['seed']}, code {training['code_version']}")]
    held = metrics["held_out_episodes"]
    machines = "; ".join(f"{m}: F21 MAPE {v['f21_mape_pct']:.1f} %, interval coverage {v['interval_coverage']:.2f}"
                         for m, v in metrics["held_out_machines"].items())
    return [*common,
            ("held_out episodes", f"R² of δ1 {held['r2_dig']:.4f} (dig cycles), {held['r2']:.4f} (all rows); "
                                  f"F21 MAPE {held['f21_mape_pct']:.2f} %"),
            ("held_out machines", machines),
            ("miniature", f"mean abs. error {metrics['mini']['mean_abs_pct_error']:.2f} % (direct-Pi "
                          f"{metrics['mini']['direct_pi_mean_abs_pct_error']:.1f} %)"),
            ("training", f"machines {training['machines']}, soils {training['soils']}, data "
                         f"{training['data_hashes']}, seed {training['seed']}, code {training['code_version']}")]


def run_show(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

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
    for key, value in scaling_rows(card):
        table.add_row(key, escape(value))  # units in brackets are not rich markup
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
