"""``scaletwin dataset``: a resumable sweep of recorded episodes (scales × soils × piles × seeds) to Parquet, in local
processes or on Ray, into a folder or a filesystem URI (``s3://bucket/prefix``, ``file:///data/run``)."""

from __future__ import annotations

import argparse

from scaletwin.cli import CommandError
from scaletwin.cli.common import add_executor_args, add_law_arg, check_law, executor_from_args, scale_arg


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("dataset", help="record a grid of dig episodes into a Parquet dataset (resumable)")
    p.add_argument("out", help="dataset folder or filesystem URI such as s3://bucket/prefix (one "
                               "ep-<hash>.parquet per episode, plus manifest.json)")
    p.add_argument("--scales", nargs="+", type=scale_arg, default=["mini"],
                   help="presets or length ratios vs the ER12 (default mini)")
    add_law_arg(p)
    p.add_argument("--soils", nargs="+", default=["gravel"], help="soil names (default gravel)")
    p.add_argument("--pile-distances", nargs="+", type=float, default=[0.5],
                   help="edge-to-pile distances at reset, boom lengths (default 0.5)")
    p.add_argument("--pile-heights", nargs="+", type=float, default=[0.7],
                   help="pile heights, boom lengths (default 0.7)")
    seeds = p.add_mutually_exclusive_group()
    seeds.add_argument("--seeds", nargs="+", type=int, help="reset seeds (default 0)")
    seeds.add_argument("--episodes", type=int, help="seeds 0..N-1 for every grid point")
    p.add_argument("--policy", default="scripted",
                   help="'scripted' or a policy factory 'package.module:function' (default scripted)")
    p.add_argument("--workers", type=int, default=None, help="local processes (default: all cores; 1 = serial)")
    add_executor_args(p)
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from scaletwin_envs.recording.sweep import SweepSpec, run_sweep

    if args.episodes is not None and args.episodes < 1:
        raise CommandError(f"--episodes must be >= 1, got {args.episodes}")
    check_law(args.scales, args.law, "--scales")
    executor = executor_from_args(args, args.workers)
    seeds = tuple(range(args.episodes)) if args.episodes else tuple(args.seeds or (0,))
    spec = SweepSpec(scales=tuple(args.scales), soils=tuple(args.soils), pile_distances=tuple(args.pile_distances),
                     pile_heights=tuple(args.pile_heights), seeds=seeds, policy=args.policy, law=args.law)
    result = run_sweep(spec, args.out, executor=executor, progress=not args.no_progress)
    recorded = result.ran - result.failed  # ``ran`` counts every episode attempted now, the failed ones too
    rate = result.ran / result.seconds if result.seconds > 0 else float("nan")
    print(f"{result.out_dir}: {recorded} recorded, {result.skipped} already present, {result.failed} failed "
          f"({result.seconds:.1f} s, {rate:.2f} episodes/s attempted)")
    failed = [e for e in result.manifest["episodes"].values() if e["status"] == "failed"]
    for e in failed[:5]:
        print(f"  failed {e['file']}: {e.get('error')}")
    return 1 if failed else 0
