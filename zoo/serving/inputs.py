"""Physical quantities in, SI arrays out: the input side of serving (DataFrames, dicts, Series, arrays, files).

Accepted forms of the rows of a machine (source or target):

* a :class:`pandas.DataFrame` (or a CSV/Parquet file, :func:`read_table`) whose columns are either ``name [unit]``
  (e.g. ``F31 [kN]``, ``x_b [mm]``; converted to SI with pint) or plain ``name`` in SI (the units of
  :data:`scaletwin_envs.signal_units.QUANTITY_UNITS`, the recorded and the design signals; a frame's
  ``attrs["units"]``, as recordings carry, is checked);
* a scaletwin :class:`~scaletwin_envs.recording.Recording` (its SI table and units);
* a mapping ``{name or "name [unit]": value or array}`` (one row per element), a list of such mappings (one per
  row), or a :class:`pandas.Series` (one row);
* a NumPy array of shape ``(n, v)`` or ``(v,)`` whose columns are the model's variables in order, SI.

Every problem is a :class:`InputError` (a ``ValueError``) naming the column: missing quantities, units of the wrong
dimension, unknown units, non-numeric or non-finite values. Nothing is silently dropped or filled in. A file that
cannot be read (truncated, not text, not CSV) or that names a column twice is an :class:`InputError` naming the file.
tests/test_bad_files.py feeds these functions mangled files generated with hypothesis.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow.parquet as pq

from scaletwin_envs.recording.importer import to_si
from scaletwin_envs.recording.recording import Recording, read_recording
from scaletwin_envs.recording.schema import METADATA_KEY
from scaletwin_envs.signal_units import QUANTITY_UNITS

Rows = (pd.DataFrame | pd.Series | Mapping[str, Any] | Sequence[Mapping[str, Any]] | Recording | np.ndarray
        | Sequence[float])
_HEADER = re.compile(r"^\s*(?P<name>[^\[\]]+?)\s*\[(?P<unit>[^\[\]]*)\]\s*$")



class InputError(ValueError):
    """Rows given to a scaling model are unusable: a quantity is missing, has the wrong unit, or is not finite."""


def split_header(header: object) -> tuple[str, str | None]:
    """``"F31 [kN]"`` → ``("F31", "kN")``; ``"F31"`` → ``("F31", None)`` (SI implied)."""
    text = str(header)
    m = _HEADER.match(text)
    return (m["name"], m["unit"]) if m else (text.strip(), None)


def si_unit(name: str) -> str:
    """The SI unit of a signal (``"N"`` for ``F31``)."""
    if name not in QUANTITY_UNITS:
        raise InputError(f"unknown quantity {name!r}")
    return QUANTITY_UNITS[name]


def header(name: str) -> str:
    """``name [SI unit]`` of a signal: the column header files and outputs use."""
    return f"{name} [{si_unit(name)}]"


def unit_factor(name: str, unit: str | None) -> float:
    """Factor converting a value of ``name`` in ``unit`` to SI (1 for ``None``: already SI).

    Raises:
        InputError: unknown unit, or a unit whose dimension is not the quantity's (e.g. ``F31 [m]``).
    """
    if unit is None:
        return 1.0
    try:
        return float(to_si(np.ones(1), unit, si_unit(name))[0])
    except Exception as exc:  # pint raises many types on bad text (undefined, syntax, ZeroDivisionError, assertions)
        why = " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(f"column {name!r}: unit {unit!r} cannot be converted to {si_unit(name)!r} ({why})") from exc


def column_plan(headers: Sequence[object], variables: Sequence[str], units: Mapping[str, str] | None = None,
                what: str = "target") -> tuple[list[int], np.ndarray]:
    """(column index, SI factor) of each of ``variables`` among ``headers`` (``name`` or ``name [unit]``).

    ``units`` (name → unit) gives the unit of plain-named columns (e.g. a recording frame's ``attrs["units"]``).

    Raises:
        InputError: a variable is missing or given twice, or its unit does not convert.
    """
    found: dict[str, tuple[int, str | None]] = {}
    for i, h in enumerate(headers):
        name, unit = split_header(h)
        if name in variables:
            if name in found:
                first = headers[found[name][0]]
                raise InputError(f"{what}: quantity {name!r} is given twice (columns {first!r} and {h!r})")
            found[name] = (i, unit if unit is not None else (units or {}).get(name))
    missing = [v for v in variables if v not in found]
    if missing:
        need = ", ".join(header(v) for v in missing)
        raise InputError(f"{what}: missing quantities: {need} (columns 'name [unit]', or plain names in SI)")
    try:
        return [found[v][0] for v in variables], np.array([unit_factor(v, found[v][1]) for v in variables])
    except InputError as exc:
        raise InputError(f"{what}: {exc}") from None


def to_matrix(rows: Rows, variables: Sequence[str], what: str = "target") -> np.ndarray:
    """The ``variables`` of ``rows`` in SI as a float64 array ``(n, len(variables))``; see the module docstring.

    Raises:
        InputError: as :func:`column_plan`, plus non-numeric or non-finite values (NaN, inf) and bad shapes.
    """
    if isinstance(rows, Recording):
        rows = recording_frame(rows)
    elif isinstance(rows, pd.Series):
        rows = rows.to_frame().T
    elif isinstance(rows, list) and rows and all(isinstance(r, Mapping) for r in rows):
        rows = pd.DataFrame(rows)
    if isinstance(rows, pd.DataFrame):
        idx, factor = column_plan(list(rows.columns), variables, rows.attrs.get("units"), what)
        values = _numeric([rows.iloc[:, i] for i in idx], variables, what)
    elif isinstance(rows, Mapping):
        keys = list(rows)
        idx, factor = column_plan(keys, variables, what=what)
        values = _numeric([np.atleast_1d(rows[keys[i]]) for i in idx], variables, what)
    else:
        values = _array(rows, variables, what)
        factor = np.ones(len(variables))
    out = values * factor
    _check_finite(out, variables, what)
    return out


def _numeric(columns: list[Any], variables: Sequence[str], what: str) -> np.ndarray:
    lengths = {len(c) for c in columns}
    if len(lengths) != 1:
        raise InputError(f"{what}: quantities have different lengths {sorted(lengths)}")
    out = np.empty((lengths.pop(), len(columns)))
    for j, (name, col) in enumerate(zip(variables, columns, strict=True)):
        try:
            out[:, j] = np.asarray(col, dtype=float)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{what}: quantity {name!r} is not numeric ({exc})") from exc
    return out


def _array(rows: Any, variables: Sequence[str], what: str) -> np.ndarray:
    try:
        arr = np.asarray(rows, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{what}: expected a DataFrame, a mapping or a numeric array ({exc})") from exc
    arr = arr.reshape(1, -1) if arr.ndim == 1 else arr
    if arr.ndim != 2 or arr.shape[1] != len(variables):
        raise InputError(f"{what}: an array needs shape (n, {len(variables)}) with columns {list(variables)} (SI), "
                         f"got {np.shape(rows)}")
    return arr


def _check_finite(values: np.ndarray, variables: Sequence[str], what: str) -> None:
    bad = ~np.isfinite(values)
    if bad.any():
        cols = [f"{variables[j]} ({int(bad[:, j].sum())} rows, first row {int(np.argmax(bad[:, j]))})"
                for j in np.flatnonzero(bad.any(axis=0))]
        raise InputError(f"{what}: non-finite values (NaN or inf) in {', '.join(cols)}")


def read_table(path: str | Path) -> pd.DataFrame:
    """A CSV or Parquet file as a frame (headers kept as written; a scaletwin recording's units in ``attrs``).

    Raises:
        FileNotFoundError: no such file.
        InputError: another suffix than ``.csv``/``.parquet``, a file that cannot be read (truncated, binary,
            malformed: the reader's message on one line) or a header written twice; the message starts with the path.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".parquet"):
        raise InputError(f"{path}: use a .csv or .parquet file")
    try:
        return _read_csv(path) if suffix == ".csv" else _read_parquet(path)
    except InputError:
        raise
    except Exception as exc:  # pandas, pyarrow, codecs, the recording reader: whatever a damaged file raises
        why = " ".join(str(exc).split())
        raise InputError(f"{path}: cannot read the file ({type(exc).__name__}: {why})") from exc


def _read_csv(path: Path) -> pd.DataFrame:
    # pandas renames a repeated header ("F31 [N]" → "F31 [N].1"), which would hide the second column: the header
    # row is read again as data to see the names as written
    _check_unique(pd.read_csv(path, header=None, nrows=1, dtype=str).iloc[0].dropna().tolist(), path)
    return pd.read_csv(path)


def _read_parquet(path: Path) -> pd.DataFrame:
    schema = pq.read_schema(path)
    _check_unique(schema.names, path)
    if METADATA_KEY in (schema.metadata or {}):
        return recording_frame(read_recording(path))
    return pd.read_parquet(path)


def _check_unique(headers: Sequence[str], path: Path) -> None:
    seen: set[str] = set()
    for h in headers:
        if h in seen:
            raise InputError(f"{path}: column {h!r} appears more than once")
        seen.add(h)


def recording_frame(recording: Recording) -> pd.DataFrame:
    """A recording's table with its units in ``attrs["units"]``."""
    frame = recording.data.copy()
    frame.attrs["units"] = dict(recording.units)
    return frame


def write_table(frame: pd.DataFrame, path: str | Path) -> Path:
    """Write ``frame`` as CSV or Parquet (by suffix); returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".parquet":
        frame.to_parquet(path, index=False)
    elif path.suffix.lower() == ".csv":
        frame.to_csv(path, index=False)
    else:
        raise InputError(f"{path.name}: use a .csv or .parquet file")
    return path
