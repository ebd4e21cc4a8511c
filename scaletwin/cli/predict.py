"""``scaletwin predict``: scale F21 from a source machine's recording to a target machine's quantities.

    scaletwin predict --model ffnn-eq10 --target wa475.csv [--source er12.parquet] [--out scaled.csv]
    scaletwin predict --model statics-pl-ens --target new.csv --source a.csv --source b.csv --source c.csv

Files are CSV or Parquet with ``name [unit]`` headers (any unit pint converts, e.g. ``F31 [kN]``, ``x_b [mm]``) or
scaletwin recordings. The source is one row of the calibrated machine (``--source-row``, default: the file's only
row; of a longer recording, the row closest to the model's calibrated reference row; for a product-line model such
as ``statics-pl``, every target row's nearest source row in pose and fill) or one row per target row;
without ``--source`` the model's own calibrated reference row is used. A model calibrated for several sources
(``statics-pl-ens``: 3) takes ``--source`` once per calibrated machine, each paired row by row with the target, and
scales from their geometric mean with the interval and error score calibrated for that many. The output holds the
target's ``machine``/``episode``/``t``/``time`` columns (if any) and ``F21 [N]``, ``F21_lower [N]``, ``F21_upper [N]``,
``delta1 [1]``, ``extrapolated`` (and ``risk [1]`` where the model serves an error score); it is printed as CSV
when ``--out`` is not given.

Every ``name [unit]`` header of both files is checked, whether or not the model uses the column: a quantity
scaletwin knows (``F21``, ``x_b``, ``time``...) whose unit pint cannot parse or whose dimension is wrong (``F21
[furlongs]``) is an error naming the file and the column; a column of another name whose unit pint cannot parse
is reported as a warning (the model never reads it, and logs carry such columns, e.g. ``operator [initials]``).
A file that cannot be read (truncated Parquet, binary CSV...), that names a column twice or has no rows is an error
naming the file, and so is every problem with the values the model reads (missing, non-numeric, NaN, inf): one line,
exit code 2. tests/test_bad_files.py tries mangled files.
"""

from __future__ import annotations

import argparse
import re
import sys
import warnings
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

from scaletwin.cli import CommandError

if TYPE_CHECKING:
    import pandas as pd

    from zoo.serving import ScalingModel

KEEP = ("machine", "episode", "t", "time")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("predict", help="scale F21 to a target machine with a zoo model (CSV/Parquet with units)")
    p.add_argument("--model", required=True, help="registered zoo name (scaletwin zoo list) or checkpoint directory")
    p.add_argument("--target", required=True, help="target machine's quantities: CSV or Parquet, 'name [unit]'")
    p.add_argument("--source", action="append",
                   help="source machine's recording (default: the model's calibrated reference row); give it once "
                        "per source machine for a model calibrated for several (statics-pl-ens: 3)")
    p.add_argument("--source-row", type=int, help="row of --source to use for every target row (0-based)")
    p.add_argument("--out", help="output .csv or .parquet (default: CSV on stdout)")
    p.add_argument("--coverage", type=float, help="interval level (default: the card's)")
    p.add_argument("--hold", type=int, help="recurrent models: each target row is the machine held still this "
                                            "many steps (static operating points)")
    p.add_argument("--threads", type=int, help="cores for the batch (default: every usable core)")
    p.set_defaults(func=run)


def unit_problems(headers: Sequence[object]) -> tuple[list[str], list[str]]:
    """(errors, warnings) about the units of ``name [unit]`` headers; plain names (SI) are not checked.

    An error: a quantity scaletwin knows (:func:`scaletwin_envs.recording.schema.known_units`) whose unit pint
    cannot parse or whose dimension is not the quantity's. A warning: another name whose unit pint cannot parse.
    """
    import numpy as np

    from scaletwin_envs.recording.importer import to_si
    from scaletwin_envs.recording.schema import NON_QUANTITY, known_units
    from zoo.serving.inputs import split_header

    known = known_units()
    errors: list[str] = []
    notes: list[str] = []
    for header in headers:
        name, unit = split_header(header)
        si = known.get(name)
        if unit is None or si == NON_QUANTITY:
            continue
        try:  # to itself for an unknown name: whether pint parses the unit at all
            to_si(np.ones(1), unit, si if si is not None else unit)
        except Exception as exc:  # pint raises many types for a bad unit (undefined, syntax, even assertions)
            why = " ".join(str(exc).split()) or type(exc).__name__
            if si is not None:
                errors.append(f"column {str(header)!r}: unit {unit!r} is not a unit of {name} (SI {si!r}): {why}")
            else:
                notes.append(f"column {str(header)!r}: pint does not know the unit {unit!r} ({why}); "
                             "the column is not a quantity scaletwin uses, and is ignored")
    return errors, notes


def read_input(path: str, role: str) -> pd.DataFrame:
    """``path`` read with :func:`zoo.serving.read_table`, every failure and every unit error naming the file
    (``role``: "target" or "source"); unit warnings are printed to stderr.

    Raises:
        FileNotFoundError: no such file.
        CommandError: the file cannot be read, names a column twice, has no rows, or a unit error.
    """
    from zoo.serving import InputError, read_table

    try:
        frame = read_table(path)
    except InputError as exc:  # its message starts with the path
        raise CommandError(f"{role} {exc}") from exc
    if frame.empty:
        raise CommandError(f"{role} {path}: no rows")
    errors, notes = unit_problems(list(frame.columns))
    if errors:
        raise CommandError(f"{role} {path}: " + "; ".join(errors))
    for note in notes:
        print(f"scaletwin predict: warning: {role} {path}: {note}", file=sys.stderr)
    return frame


def naming_files(exc: Exception, files: Mapping[str, str | None]) -> CommandError:
    """A model's :class:`~zoo.serving.InputError` as a one-line :class:`CommandError` naming the file: a message
    that starts with the role ("target", "source") gets that file's path after it (``files``: role → path, ``None``
    for the model's own reference row)."""
    text = " ".join(str(exc).split())
    role = re.match(r"(target|source)\b", text)
    if role and files.get(role[1]):
        text = f"{role[1]} {files[role[1]]}{text[role.end():]}"
    return CommandError(text)


def matched_source(source: pd.DataFrame, target: pd.DataFrame,
                   files: Mapping[str, str | None] | None = None) -> pd.DataFrame:
    """One source row per target row for a product-line model (:func:`scaling.data.product_line.match_rows`): nearest in
    boom angle and bucket pitch (and fill, where both files have it), of the same ``kind`` where both have one.

    Raises:
        CommandError: a file lacks the boom angle or the bucket pitch, or their values are unusable (``files``:
            role → path, for the message).
    """
    import pandas as pd

    from scaling.data.product_line import MATCH_KEYS, MATCH_WEIGHTS, match_rows
    from zoo.serving import InputError
    from zoo.serving.inputs import split_header, to_matrix

    names = {split_header(c)[0] for c in source.columns} & {split_header(c)[0] for c in target.columns}
    keys = [k for k in MATCH_KEYS if k in names]
    if not {"boom_angle", "bucket_pitch"} <= set(keys):
        raise CommandError("a product-line model pairs every target row with its nearest source row in pose: both "
                           "files need boom_angle and bucket_pitch (and fill, load / rated load, where known)")
    try:
        frames = [pd.DataFrame(to_matrix(f, keys, role), columns=keys) for f, role in ((source, "source"),
                                                                                      (target, "target"))]
    except InputError as exc:
        raise naming_files(exc, files or {}) from exc
    if "kind" in source.columns and "kind" in target.columns:  # dig rows to dig rows, holds to holds
        for frame, raw in zip(frames, (source, target), strict=True):
            frame["kind"] = raw["kind"].astype(str).to_numpy()
    idx = match_rows(frames[0], frames[1], keys, [MATCH_WEIGHTS[MATCH_KEYS.index(k)] for k in keys])
    print(f"scaletwin predict: each of the {len(target)} target rows paired with its nearest of the {len(source)} "
          f"source rows in {', '.join(keys)} (a product-line model; --source-row picks one row for all)",
          file=sys.stderr)
    return source.iloc[idx].reset_index(drop=True)


def pick_source(model: ScalingModel, source: pd.DataFrame, target: pd.DataFrame, row: int | None,
                files: Mapping[str, str | None]) -> pd.DataFrame:
    """The source rows to scale from: row ``row`` (``--source-row``); every target row's matched row for a
    product-line model; the file's only row or one per target row as given; else the row nearest the model's
    calibrated reference."""
    from zoo.serving import InputError

    if row is not None:
        if not 0 <= row < len(source):
            raise CommandError(f"--source-row {row} is outside the {len(source)} source rows")
        return source.iloc[[row]]
    if model.include_source and len(source) != len(target):
        return matched_source(source, target, files)
    if len(source) in (1, len(target)):
        return source
    try:
        nearest = model.nearest_source_row(source)
    except InputError as exc:
        raise naming_files(exc, files) from exc
    print(f"scaletwin predict: source row {nearest} of {len(source)} (the closest to the model's calibrated "
          "reference row; choose another with --source-row)", file=sys.stderr)
    return source.iloc[[nearest]]


def run(args: argparse.Namespace) -> int:
    import zoo
    from zoo.serving import InputError, ScalingModel, write_table
    from zoo.serving.inputs import split_header

    target = read_input(args.target, "target")
    paths = list(args.source or [])
    sources = [read_input(path, "source") for path in paths]
    files = {"target": args.target, "source": ", ".join(paths) or None}
    try:
        model = zoo.load(args.model)
    except zoo.CheckpointError as exc:
        raise CommandError(str(exc)) from exc
    if not isinstance(model, ScalingModel):
        raise CommandError(f"{args.model} is a {type(model).__name__}, not a scaling model (scaletwin zoo list)")
    if len(sources) > 1:
        if model.calibrated_sources != len(sources):
            raise CommandError(f"{model.name} is calibrated for "
                               f"{model.calibrated_sources or 1} source(s), not {len(sources)}: give --source "
                               f"{model.calibrated_sources or 1} time(s)")
        if args.source_row is not None or args.hold is not None:
            raise CommandError("--source-row and --hold take one --source")
    sources = [pick_source(model, src, target, args.source_row, {**files, "source": path})
               for src, path in zip(sources, paths, strict=True)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", zoo.ExtrapolationWarning)
        warnings.simplefilter("always", zoo.SourceWarning)
        try:
            if len(sources) > 1:
                result = model.scale_force_sources(sources, target, coverage=args.coverage, threads=args.threads)
            else:
                result = model.scale_force(sources[0] if sources else None, target, coverage=args.coverage,
                                           hold=args.hold, threads=args.threads)
        except InputError as exc:
            raise naming_files(exc, files) from exc
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
