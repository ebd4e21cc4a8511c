"""Import an external recording (a real machine's log) from CSV or Parquet, converting every column to SI.

Headers are ``name [unit]``, e.g. ``F21 [kN]``, ``Pf_lift [MPa·m²]``, ``x_b [mm]``, ``time [ms]``; ``name`` is a
column of :mod:`scaletwin_envs.recording.schema` and ``unit`` anything pint converts to that column's SI unit
(``·``, ``²``, ``³``, ``^`` and ``%`` are accepted; ``[1]``, ``[-]`` or ``[]`` mark pure numbers). ``phase`` and
``step`` may omit the unit. Joint columns ``q_<joint>``/``qd_<joint>`` take an angle (→ rad, rad/s) or a length
(→ m, m/s).

Required (:data:`~scaletwin_envs.recording.schema.REQUIRED_IMPORT`): ``time``, the three commands (the twin
must be able to replay the episode) and the Eq. (10)/(23) signals F21, F31, Pf_tilt, Pf_lift, x_b, y_b, m_b,
a1, alpha1, V1, w1 (what the scaling models are fitted on); ``required=`` relaxes that for users that need fewer
(the discrepancy tool needs time and the commands, and compares whatever signals are there). Every other column
is optional; columns that are absent stay absent (nothing is invented). Unknown columns are an error unless
``ignore_unknown=True``.

Data-logger CSVs are read as they come: ``,``, ``;`` or tab as the delimiter, a UTF-8 byte-order mark, spaces
around headers, and empty trailing columns (from a trailing delimiter) are accepted; empty cells are NaN.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import re
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pint
import pyarrow.parquet as pq

from scaletwin_envs.recording.recording import Provenance, Recording, read_recording
from scaletwin_envs.recording.schema import METADATA_KEY, NON_QUANTITY, REQUIRED_IMPORT, known_units

_HEADER = re.compile(r"^\s*(?P<name>[^\[\]]+?)\s*(?:\[(?P<unit>[^\[\]]*)\])?\s*$")
_UNITLESS_OK = frozenset({"phase", "step"})
_DIMENSIONLESS = frozenset({"", "1", "-", "dimensionless"})
_REPLACE = (("·", "*"), ("⋅", "*"), ("²", "**2"), ("³", "**3"), ("^", "**"), ("−", "-"), ("%", "percent"))
#: Delimiters a data logger writes: comma, semicolon (locales with a decimal comma), tab.
_DELIMITERS = ",;\t"


#: Superscript characters: pint reads a run of them as one exponent (``m⁻¹``); the importer first rewrites ``²`` and
#: ``³`` as ``**2`` and ``**3``, so that ``N²²`` becomes ``N**2**2``.
_SUPERSCRIPTS = "⁰¹²³⁴⁵⁶⁷⁸⁹⁻⁺"
#: One token of a unit expression, as far as :func:`check_unit_expression` cares.
_UNIT_TOKEN = re.compile(rf"(?P<power>\*\*|\^)|(?P<superscript>[{_SUPERSCRIPTS}]+)"
                         r"|(?P<number>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)"
                         rf"|(?P<name>[^\W\d{_SUPERSCRIPTS}][^\W{_SUPERSCRIPTS}]*)|(?P<other>.)", re.DOTALL)
#: What may follow ``**`` or ``^``: a number of at most three digits (``2``, ``-2``, ``0.5``) or a fraction ``(1/2)``.
_EXPONENT = re.compile(r"\s*(?:[+\-−]?\s*\d{1,3}(?:\.\d{1,3})?(?![\d.])"
                       r"|\(\s*[+\-−]?\s*\d{1,3}\s*(?:/\s*\d{1,3}\s*)?\))")


def check_unit_expression(unit: str) -> None:
    """Refuse a unit text whose evaluation could run away, before pint sees it.

    pint evaluates the numbers of a unit expression as Python numbers, so ``10**10**10`` (or ``N²²²²²²``, which
    reads as ``N**2**2**2**2**2**2``) would build an integer of billions of digits: the read would hang. Accepted:
    exponents of at most three digits (``m**2``, ``s^-2``, ``m**0.5``, ``m**(1/2)``, ``m²``, ``m⁻¹``), none raised
    again (``m**2**3``, ``m²²``), and no number outside an exponent but 1 (``1/s``; pint refuses other factors in a
    unit anyway).

    Raises:
        ValueError: a chained, long or non-numeric exponent, or a number other than 1.
    """
    pos, after_exponent = 0, False
    while pos < len(unit):
        token = _UNIT_TOKEN.match(unit, pos)
        assert token is not None  # the last alternative matches any character
        kind, text = token.lastgroup, token.group()
        pos = token.end()
        if kind in ("power", "superscript"):
            if after_exponent:
                raise ValueError(f"unit {unit!r}: an exponent raised to a power again")
            if kind == "superscript" and len(text) > (1 if set(text) & set("²³") else 3):
                raise ValueError(f"unit {unit!r}: the superscript exponent {text} is not accepted (write it with "
                                 "** or ^)")
            if kind == "power":
                exponent = _EXPONENT.match(unit, pos)
                if exponent is None:
                    raise ValueError(f"unit {unit!r}: an exponent must be a number of at most three digits or a "
                                     "fraction such as (1/2)")
                pos = exponent.end()
            after_exponent = True
        elif kind == "number" and float(text) != 1.0:
            raise ValueError(f"unit {unit!r}: the number {text} is not a unit (a unit carries no scaling factor)")
        elif not text.isspace():
            after_exponent = False


@lru_cache(maxsize=1)
def unit_registry() -> pint.UnitRegistry:
    """The pint registry used for conversions (created on first use)."""
    return pint.UnitRegistry()


def to_si(values: np.ndarray, unit: str, si_unit: str) -> np.ndarray:
    """``values`` in ``unit`` converted to ``si_unit``.

    Raises:
        ValueError: unknown unit, or a unit of another dimension than ``si_unit``.
    """
    ureg = unit_registry()
    try:
        src, dst = _parse(unit), _parse(si_unit)
        have, want = ureg.Quantity(1.0, src).dimensionality, ureg.Quantity(1.0, dst).dimensionality
    except AssertionError as exc:  # pint's parser asserts on some malformed strings (e.g. "kN/")
        raise ValueError(f"{unit!r} is not a unit expression pint can parse") from exc
    if have != want:
        raise ValueError(f"its dimension is {have}, not {want}")
    return np.asarray(ureg.Quantity(np.asarray(values, dtype=np.float64), src).to(dst).magnitude, dtype=np.float64)


def import_recording(path: str | Path, *, provenance: Provenance | None = None,
                     ignore_unknown: bool = False, required: Sequence[str] = REQUIRED_IMPORT) -> Recording:
    """Read a CSV or Parquet log with ``name [unit]`` headers into an SI :class:`Recording`.

    A scaletwin Parquet recording (with its metadata) is simply read back with :func:`read_recording`.

    Args:
        path: ``.csv`` or ``.parquet`` file.
        provenance: what is known about the machine (spec, soil, seed, ...); ``source`` becomes ``"import"``
            and ``extra`` gains the file name, its SHA-256 and the original headers.
        ignore_unknown: drop unknown columns instead of failing.
        required: columns that must be present (default :data:`REQUIRED_IMPORT`).

    Raises:
        FileNotFoundError: no such file.
        ValueError: missing required columns, unknown columns, or unknown/inconvertible units; the message
            lists every problem and the expected headers with their SI units.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no recording at {path}")
    if path.suffix.lower() == ".parquet" and METADATA_KEY in (pq.read_schema(path).metadata or {}):
        return read_recording(path)
    raw = _read_table(path)
    columns, units, problems = _convert(raw, ignore_unknown)
    named = {_split(h)[0] for h in raw.columns}
    missing = [c for c in required if c not in named]
    if missing:
        problems.insert(0, f"missing required columns: {', '.join(missing)}")
    if problems:
        raise ValueError(f"cannot import {path.name}:\n  " + "\n  ".join(problems) + "\n" + expected_headers())
    frame, units = _assemble(columns, units, len(raw))
    extra = {"file": path.name, "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
             "headers": [str(c) for c in raw.columns]}
    base = provenance or Provenance(policy="external")
    prov = dataclasses.replace(base, source="import", extra={**base.extra, "import": extra})
    return Recording(frame, units, prov)


def expected_headers() -> str:
    """Human-readable list of accepted headers with their SI units (used in error messages)."""
    known = known_units()
    required = ", ".join(f"{c} [{known[c]}]" for c in REQUIRED_IMPORT)
    optional = ", ".join(f"{c} [{u}]" for c, u in known.items() if c not in REQUIRED_IMPORT)
    return ("expected headers 'name [unit]' (SI unit shown; any unit convertible to it is accepted):\n"
            f"  required: {required}\n  optional: {optional}, q_<joint> [rad or m], qd_<joint> [rad/s or m/s]")


def _read_table(path: Path) -> pd.DataFrame:
    suffix = path.suffix.lower()
    if suffix == ".csv":
        frame = pd.read_csv(path, sep=_delimiter(path), encoding="utf-8-sig", skipinitialspace=True)
        trailing = [c for c in frame.columns if str(c).startswith("Unnamed:") and frame[c].isna().all()]
        return frame.drop(columns=trailing)
    if suffix == ".parquet":
        return pd.read_parquet(path)
    raise ValueError(f"cannot import {path.name}: use a .csv or .parquet file")


def _delimiter(path: Path) -> str:
    """The delimiter of the header line (a comma when the line has none of :data:`_DELIMITERS`)."""
    with path.open(encoding="utf-8-sig", newline="") as f:
        header = f.readline()
    try:
        return csv.Sniffer().sniff(header, delimiters=_DELIMITERS).delimiter
    except csv.Error:
        return ","


def _convert(raw: pd.DataFrame, ignore_unknown: bool) -> tuple[dict[str, Any], dict[str, str], list[str]]:
    known = known_units()
    columns: dict[str, Any] = {}
    units: dict[str, str] = {}
    problems: list[str] = []
    for header in raw.columns:
        name, unit = _split(header)
        is_joint = name.startswith(("q_", "qd_"))
        if name not in known and not is_joint:
            if not ignore_unknown:
                problems.append(f"unknown column {header!r}")
            continue
        if name in columns:
            problems.append(f"column {name!r} appears twice")
            continue
        if unit is None:
            if name not in _UNITLESS_OK:
                problems.append(f"column {header!r} has no unit: write it as '{name} [{known.get(name, 'unit')}]'")
                continue
            unit = known[name]
        si = _joint_unit(name, unit) if is_joint else known[name]
        try:
            columns[name] = raw[header].to_numpy() if si == NON_QUANTITY else to_si(raw[header].to_numpy(), unit, si)
            units[name] = si
        except (ValueError, pint.PintError) as exc:
            problems.append(f"column {header!r}: unit {unit!r} is not convertible to {si!r}: {exc}")
    return columns, units, problems


def _split(header: object) -> tuple[str, str | None]:
    """``"F21 [kN]"`` → ``("F21", "kN")``; a header without brackets has no unit (None)."""
    m = _HEADER.match(str(header))
    return (m["name"], m["unit"]) if m else (str(header), None)


def _joint_unit(name: str, unit: str) -> str:
    rate = name.startswith("qd_")
    try:
        q = unit_registry().Quantity(1.0, _parse(unit))
    except (ValueError, pint.PintError):
        return "rad/s" if rate else "rad"  # the conversion reports the bad unit
    is_length = "[length]" in q.dimensionality
    return ("m/s" if rate else "m") if is_length else ("rad/s" if rate else "rad")


def _assemble(columns: dict[str, Any], units: dict[str, str], rows: int) -> tuple[pd.DataFrame, dict[str, str]]:
    order = [c for c in known_units() if c in columns]
    order += sorted(c for c in columns if c not in order)
    cols = {c: columns[c] for c in order}
    if "step" in cols:
        cols["step"] = np.asarray(cols["step"], dtype=np.int64)
    else:
        cols = {"step": np.arange(1, rows + 1, dtype=np.int64), **cols}
        units = {"step": "1", **units}
    if "phase" in cols:
        cols["phase"] = pd.array([str(p) for p in cols["phase"]], dtype="str")
    return pd.DataFrame(cols), {c: units[c] for c in cols}


def _parse(unit: str) -> str:
    check_unit_expression(unit)
    text = unit.strip()
    if text.lower() in _DIMENSIONLESS:
        return "dimensionless"
    for old, new in _REPLACE:
        text = text.replace(old, new)
    try:
        unit_registry().parse_units(text)  # raises UndefinedUnitError for unknown units
    except pint.PintError:
        raise
    except Exception as exc:  # pint's parser raises other types on malformed text (tokenize.TokenError for "((((",
        # TypeError for "1-A"): they escaped the per-column report and the file was refused as corrupted, the
        # column unnamed
        raise ValueError(f"{unit!r} is not a unit expression pint can parse ({type(exc).__name__}: {exc})") from exc
    return text
