"""``scaletwin predict``: scale F21 from a source machine's recording to a target machine's quantities.

    scaletwin predict --model ffnn-eq10 --target wa475.csv [--source er12.parquet] [--out scaled.csv]
    scaletwin predict --model statics-pl-ens --target new.csv --source a.csv --source b.csv --source c.csv
    scaletwin predict --model statics-pl --target new.csv --target-design new.json
                      --source er12.csv --source-design er12

Files are CSV or Parquet with ``name [unit]`` headers (any unit pint converts, e.g. ``F31 [kN]``, ``x_b [mm]``) or
scaletwin recordings. The source is one row of the calibrated machine (``--source-row``, default: the file's only
row; of a longer recording, the row closest to the model's calibrated reference row; for a product-line model such
as ``statics-pl``, every target row's nearest source row in pose and fill) or one row per target row;
without ``--source`` the model's own calibrated reference row is used. A model calibrated for several sources
(``statics-pl-ens``: 3) takes ``--source`` once per calibrated machine, each paired row by row with the target, and
scales from their geometric mean with the interval and risk calibrated for that many. A product-line model
reads design signals no sensor gives (``tilt_ratio``, ``fill``, ``F21_linkage``...); files without
them name each machine's design (``--target-design``, ``--source-design``: a preset, a length ratio, a LoaderSpec
JSON) and the signals are computed from the pose, cylinder extensions, payload and tilt-cylinder force
(:func:`scaling.data.product_line.add_design_signals`). The output holds the
target's ``machine``/``episode``/``t``/``time`` columns (if any) and ``F21 [N]``, ``F21_lower [N]``, ``F21_upper [N]``,
``delta1 [1]``, ``extrapolated`` (and ``risk [1]`` where the model serves an error score; a product-line
checkpoint whose build learnt none says so on stderr; ``stroke_end`` where the model takes the tilt stroke: the
rows whose tilt cylinder sits at an end of its stroke, warned on stderr); it is printed as CSV
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

    from scaletwin_envs.specs import LoaderSpec
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
    p.add_argument("--target-design", metavar="DESIGN",
                   help="the target machine's design, to compute its design signals (tilt_ratio, strokes, fill, "
                        "F21_linkage, tilt_load) from the file's pose, cylinder extensions, m_load and Pf_tilt: a "
                        "preset (mini, er12, wa475), a length ratio to the ER12 (product-line law), or a JSON "
                        "file: a LoaderSpec, or `scaletwin product-line`'s machines.json#NAME")
    p.add_argument("--source-design", metavar="DESIGN", action="append",
                   help="the same for a source machine, once per --source (in the same order)")
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


#: What the design signals are computed from (:func:`scaling.data.product_line.add_design_signals`), SI.
DESIGN_INPUTS = ("boom_angle", "bucket_pitch", "lift_extension", "tilt_extension", "m_load", "Pf_tilt")


def design_of(text: str, flag: str) -> LoaderSpec:
    """The machine design ``text`` names (``flag``: the option, for messages): a preset, a length ratio λ to the
    ER12 (product-line law), or a JSON file holding a :class:`~scaletwin_envs.specs.LoaderSpec` (its ``to_json``),
    one product-line machine (``{"spec": ...}``) or ``scaletwin product-line``'s ``machines.json#NAME``.

    Raises:
        CommandError: nothing of that name, an unreadable file, a JSON that is no design, a bad λ.
    """
    import json
    from pathlib import Path

    from scaletwin_envs.specs import LoaderSpec, make_loader
    from scaletwin_envs.specs.presets import PRESETS

    if text in PRESETS:
        return make_loader(text)
    try:
        return make_loader(float(text))
    except ValueError as exc:
        if not text.lower().endswith(".json") and ".json#" not in text.lower():
            if re.fullmatch(r"[-+.\deE]+", text):  # a number, out of range
                raise CommandError(f"{flag} {text}: {exc}") from exc
            raise CommandError(f"{flag} {text!r}: not a preset ({', '.join(PRESETS)}), a length ratio or a .json "
                               "design file") from exc
    path, _, name = text.partition("#")
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CommandError(f"{flag} {path}: cannot read a JSON design ({' '.join(str(exc).split())})") from exc
    if isinstance(doc, dict) and isinstance(doc.get("machines"), list):  # scaletwin product-line's machines.json
        names = [str(m.get("name")) for m in doc["machines"] if isinstance(m, dict)]
        if name not in names:
            raise CommandError(f"{flag} {text}: name a machine of the file after '#' (one of "
                               f"{', '.join(names[:8])}{'...' if len(names) > 8 else ''})")
        doc = doc["machines"][names.index(name)]
    if isinstance(doc, dict) and isinstance(doc.get("spec"), dict):
        doc = doc["spec"]
    try:
        return LoaderSpec.from_dict(doc if isinstance(doc, dict) else {})
    except (ValueError, TypeError) as exc:
        raise CommandError(f"{flag} {path}: {exc}") from exc


def with_design(frame: pd.DataFrame, spec: LoaderSpec, role: str, path: str) -> pd.DataFrame:
    """``frame`` with the design signals of ``spec`` (:data:`~scaletwin_envs.signal_units.DESIGN_SIGNAL_UNITS`, SI)
    computed from its :data:`DESIGN_INPUTS` (any units); design columns the file already had are replaced, and
    a note says so.

    Raises:
        CommandError: an input missing or unusable, naming the file.
    """
    import pandas as pd

    from scaletwin_envs.signal_units import DESIGN_SIGNAL_UNITS
    from scaling.data.product_line import add_design_signals
    from zoo.serving import InputError
    from zoo.serving.inputs import split_header, to_matrix

    try:
        si = pd.DataFrame(to_matrix(frame, DESIGN_INPUTS, f"{role} (for its design signals)"),
                          columns=list(DESIGN_INPUTS))
    except InputError as exc:
        raise CommandError(f"{role} {path}: {' '.join(str(exc).split())}") from exc
    design = add_design_signals(si.assign(machine=spec.name), {spec.name: spec})
    replaced = [c for c in frame.columns if split_header(c)[0] in DESIGN_SIGNAL_UNITS]
    if replaced:
        print(f"scaletwin predict: {role} {path}: columns {', '.join(map(str, replaced))} replaced by the design "
              f"signals of {spec.name}", file=sys.stderr)
    out = frame.drop(columns=replaced)
    return out.assign(**{name: design[name].to_numpy(float) for name in DESIGN_SIGNAL_UNITS})


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
    designs = list(args.source_design or [])
    if designs and len(designs) != len(paths):
        raise CommandError(f"give --source-design once per --source ({len(paths)}), got {len(designs)}")
    if args.target_design is not None:
        target = with_design(target, design_of(args.target_design, "--target-design"), "target", args.target)
    sources = [with_design(src, design_of(text, "--source-design"), "source", path)
               for src, text, path in zip(sources, designs, paths, strict=True)] if designs else sources
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
        warnings.simplefilter("always", zoo.EndStopWarning)
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
    reason = model.sources_risk_unavailable() if len(sources) > 1 else model.risk_unavailable
    if model.risk is not None and result.risk is None and reason:  # a product-line model whose build learnt none
        print(f"scaletwin predict: note: {model.name} serves no risk score (no risk [1] column): {reason}",
              file=sys.stderr)
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
