"""``scaletwin product-line``: sample machines of distinct design and record what each of them digs (resumable)."""

from __future__ import annotations

import argparse
import json

from scaletwin.cli import CommandError
from scaletwin.cli.common import add_executor_args, executor_from_args

#: Local processes when neither --workers nor another executor is given.
DEFAULT_WORKERS = 2


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("product-line", help="sample a product line of distinct machines and record their digs and "
                                            "holds (resumable)")
    p.add_argument("out", help="folder or filesystem URI (s3://bucket/prefix): machines.json plus one Parquet "
                               "recording per episode")
    p.add_argument("--machines", type=int, default=8, help="machines to draw (default 8)")
    p.add_argument("--seed", type=int, default=0, help="seed of the draw (machine i depends on (seed, i) only)")
    p.add_argument("--soils", nargs="+", default=["gravel", "sand", "sandy_loam", "clay_loam"],
                   help="soils every machine digs (default all four)")
    p.add_argument("--holds", type=int, default=4, help="static-hold episodes per machine (default 4)")
    p.add_argument("--presets", nargs="*", default=[], help="presets to add to the line, e.g. er12")
    p.add_argument("--workers", default=None,
                   help=f"local processes (an integer) or 'serial' (default {DEFAULT_WORKERS})")
    add_executor_args(p)
    p.add_argument("--dry-run", action="store_true", help="draw and list the machines, simulate nothing")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from scaletwin_envs.recording.atomic import join, make_dirs, write_text_atomic
    from scaling.data.product_line import ProductLine
    from scaling.data.recordings import SOILS, generate_recordings
    from scaling.runs.provenance import code_version

    if args.machines < 1:
        raise CommandError(f"--machines must be >= 1, got {args.machines}")
    if args.holds < 0:
        raise CommandError(f"--holds must be >= 0, got {args.holds}")
    if bad := sorted(set(args.soils) - set(SOILS)):
        raise CommandError(f"unknown soils {bad}; choose from {list(SOILS)}")
    executor = executor_from_args(args, args.workers)
    line = ProductLine(n_machines=args.machines, seed=args.seed, soils=tuple(args.soils),
                       hold_episodes=args.holds, presets=tuple(args.presets))
    try:
        table = line.distortions()
    except RuntimeError as exc:
        raise CommandError(str(exc)) from exc
    cols = ["machine", "scale", "operating_mass_t", "bucket_m3_per_t", "breakout_per_weight", "raise_time_s",
            "tilt_ratio_min", "tilt_ratio_max"]
    print(table[cols].to_string(index=False, float_format=lambda x: f"{x:.3g}"))
    if args.dry_run:
        return 0
    make_dirs(args.out)
    meta = {"format": "scaletwin.product_line", "code": code_version(), "line": line.to_dict(),
            "machines": [m.to_dict() for m in line.machines]}
    write_text_atomic(join(args.out, "machines.json"), json.dumps(meta, indent=1, default=str))
    spec = line.dataset_spec()
    print(f"recording {len(spec.tasks())} episodes into {args.out} (resumable: finished episodes are kept)")
    generate_recordings(spec, args.out, executor=DEFAULT_WORKERS if executor is None else executor, progress=True)
    print(f"{args.out}: done; load it with scaling.data.recordings.load_recordings and add the design signals with "
          "scaling.data.product_line.add_design_signals(frame, ProductLine(...).specs())")
    return 0
