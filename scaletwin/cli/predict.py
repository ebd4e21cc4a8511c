"""``scaletwin predict``: scale F21 from a source machine's recording to a target machine's quantities.

    scaletwin predict --model ffnn-eq10 --target wa475.csv [--source er12.parquet] [--out scaled.csv]

Files are CSV or Parquet with ``name [unit]`` headers (any unit pint converts, e.g. ``F31 [kN]``, ``x_b [mm]``) or
scaletwin recordings. The source is one row of the calibrated machine (``--source-row``, default: the file's only
row; of a longer recording, the row closest to the model's calibrated reference row) or one row per target row;
without ``--source`` the model's own calibrated reference row is used. The output holds the target's
``machine``/``episode``/``t``/``time`` columns (if any) and ``F21 [N]``, ``F21_lower [N]``, ``F21_upper [N]``,
``delta1 [1]``, ``extrapolated``; it is printed as CSV when ``--out`` is not given.
"""

from __future__ import annotations

import argparse
import sys
import warnings

from scaletwin.cli import CommandError

KEEP = ("machine", "episode", "t", "time")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("predict", help="scale F21 to a target machine with a zoo model (CSV/Parquet with units)")
    p.add_argument("--model", required=True, help="registered zoo name (scaletwin zoo list) or checkpoint directory")
    p.add_argument("--target", required=True, help="target machine's quantities: CSV or Parquet, 'name [unit]'")
    p.add_argument("--source", help="source machine's recording (default: the model's calibrated reference row)")
    p.add_argument("--source-row", type=int, help="row of --source to use for every target row (0-based)")
    p.add_argument("--out", help="output .csv or .parquet (default: CSV on stdout)")
    p.add_argument("--coverage", type=float, help="interval level (default: the card's)")
    p.add_argument("--hold", type=int, help="recurrent models: each target row is the machine held still this "
                                            "many steps (static operating points)")
    p.add_argument("--threads", type=int, help="cores for the batch (default: every usable core)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import zoo
    from zoo.serving import InputError, ScalingModel, read_table, write_table
    from zoo.serving.inputs import split_header

    try:
        model = zoo.load(args.model)
    except zoo.CheckpointError as exc:
        raise CommandError(str(exc)) from exc
    if not isinstance(model, ScalingModel):
        raise CommandError(f"{args.model} is a {type(model).__name__}, not a scaling model (scaletwin zoo list)")
    target = read_table(args.target)
    source = None
    if args.source:
        source = read_table(args.source)
        if args.source_row is not None:
            if not 0 <= args.source_row < len(source):
                raise CommandError(f"--source-row {args.source_row} is outside the {len(source)} source rows")
            source = source.iloc[[args.source_row]]
        elif len(source) not in (1, len(target)):
            try:
                row = model.nearest_source_row(source)
            except InputError as exc:
                raise CommandError(str(exc)) from exc
            print(f"scaletwin predict: source row {row} of {len(source)} (the closest to the model's calibrated "
                  "reference row; choose another with --source-row)", file=sys.stderr)
            source = source.iloc[[row]]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", zoo.ExtrapolationWarning)
        warnings.simplefilter("always", zoo.SourceWarning)
        try:
            result = model.scale_force(source, target, coverage=args.coverage, hold=args.hold,
                                        threads=args.threads)
        except InputError as exc:
            raise CommandError(str(exc)) from exc
    for w in caught:
        print(f"scaletwin predict: warning: {w.message}", file=sys.stderr)
    out = result.to_frame()
    for col in reversed([c for c in target.columns if split_header(c)[0] in KEEP]):
        out.insert(0, col, target[col].to_numpy())
    if args.out:
        write_table(out, args.out)
        print(f"{len(out)} rows → {args.out} ({model.name}, {result.interval_method} interval at "
              f"{result.coverage:.0%}; {int(result.extrapolated.sum())} extrapolated)", file=sys.stderr)
    else:
        out.to_csv(sys.stdout, index=False)
    return 0
