"""Bad field logs, property-based (issue 15): mangled CSV/Parquet logs fed to ``scaletwin diagnose``'s reader.

``scaletwin diagnose REAL --twin SPEC`` reads its log in two steps (``discrepancy.pipeline._read``/``_adapt``):
:func:`discrepancy.data.episode.read_log` (the file, converted to SI), then
:func:`discrepancy.data.episode.from_recording` twice, at the log's own step (to look for a provenance; a
:class:`RecordingError` there is set aside when ``--twin`` is given) and at the twin's control step (gaps bridged,
a faster log resampled). The properties here do the same.

Every example starts from a short real episode of the ``mini`` loader (40 control steps of the scripted dig cycle),
logged at the control step (26.5 Hz), at 50, 100 or 500 Hz (signals interpolated in time, commands held; one 500 Hz
log with jittered timestamps), or at half the control rate, and written with ``name [unit]`` headers in a data
logger's units (ms, kN, mm, bar, deg, t, km/h) or in SI. Up to four random mutations follow: a column converted to
another unit, relabelled without conversion, given a unit of another dimension, an unreadable or random unit or no
unit, dropped, written twice or again in another unit, misspelt; cells made NaN (one, a short or a long run, all),
infinite, text, empty or huge; commands out of range; timestamps swapped, repeated or jittered; unknown and known
extra columns; fewer rows. The file is written as CSV or Parquet and may then be emptied, truncated, given bytes
that are not UTF-8, a byte-order mark, CRLF line ends or another delimiter.

What the reader must do, derived from what its documentation promises (not from its code): return an episode
with finite time, commands in [-1, 1] and finite signals, the file's SI values unchanged at the control step (and
within 5 % of the signal's range after resampling a faster log), the channels it lacks reported; or raise
:class:`RecordingError` whose message names the file and, when one column is at fault, that column. Never another
exception, a hang or a silent NaN.

Besides: unit texts straight through the importer's conversion (only ValueError or pint's errors, which it
reports by column); regressions for what the properties found; and ``scaletwin diagnose`` itself on a few logs the
reader refuses (exit 2, the reader's message once, no traceback). Examples are few and fixed (50 logs per format,
500 unit texts) so that the module runs in about 10 s; ``SCALETWIN_BAD_FILES_EXAMPLES=2000`` tries thousands of
random ones (as for ``tests/test_bad_files.py``).
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from scipy.interpolate import CubicSpline

hypothesis = pytest.importorskip("hypothesis", reason='hypothesis is not installed (pip install -e ".[dev]")')
from hypothesis import HealthCheck, event, example, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from discrepancy.data.channels import COMPARED, RecordingError  # noqa: E402
from discrepancy.data.episode import MIN_STEPS, EpisodeData, from_recording, load_episode, read_log  # noqa: E402
from discrepancy.data.fieldlog import MAX_GAP_STEPS  # noqa: E402
from scaletwin.cli import main  # noqa: E402
from scaletwin_envs.recording.schema import COMMAND_COLUMNS  # noqa: E402
from scaletwin_envs.signal_units import SIGNAL_UNITS  # noqa: E402
from tests.timeouts import no_hang  # noqa: E402

#: Examples per property and format: enough to meet every mutation several times, few enough for seconds
#: ($SCALETWIN_BAD_FILES_EXAMPLES tries more, e.g. 2000, with random instead of fixed examples).
EXAMPLES = int(os.environ.get("SCALETWIN_BAD_FILES_EXAMPLES", "50"))
#: Seconds one example may take before it counts as a hang.
HANG_S = 20
#: Control steps of the recorded episode.
STEPS = 40
settings.register_profile("bad-logs", max_examples=EXAMPLES, deadline=None, derandomize=EXAMPLES <= 50,
                          database=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

#: SI unit of every column the logs carry.
SI_UNITS = {"time": "s", **dict.fromkeys(COMMAND_COLUMNS, "1"), **SIGNAL_UNITS}
#: Other units of each SI unit, with their factor to SI (value in SI = value in the unit × factor).
UNITS: dict[str, list[tuple[str, float]]] = {
    "s": [("s", 1.0), ("ms", 1e-3), ("min", 60.0)],
    "1": [("1", 1.0), ("%", 1e-2), ("-", 1.0), ("", 1.0), ("dimensionless", 1.0)],
    "N": [("N", 1.0), ("kN", 1e3), ("mN", 1e-3), ("lbf", 4.4482216152605)],
    "m": [("m", 1.0), ("mm", 1e-3), ("cm", 1e-2), ("ft", 0.3048), ("inch", 0.0254)],
    "kg": [("kg", 1.0), ("g", 1e-3), ("t", 1e3), ("lb", 0.45359237)],
    "Pa": [("Pa", 1.0), ("bar", 1e5), ("MPa", 1e6), ("psi", 6894.757293168361)],
    "m/s": [("m/s", 1.0), ("mm/s", 1e-3), ("km/h", 1 / 3.6)],
    "rad": [("rad", 1.0), ("deg", math.pi / 180)],
    "rad/s": [("rad/s", 1.0), ("deg/s", math.pi / 180), ("rpm", 2 * math.pi / 60)],
    "m/s^2": [("m/s^2", 1.0), ("mm/s**2", 1e-3), ("m/s²", 1.0)],
    "rad/s^2": [("rad/s^2", 1.0), ("deg/s^2", math.pi / 180)],
}
#: A data logger's units (the benchmark's field logs use the same kinds); a channel not listed stays SI.
LOGGER_UNITS = {"time": "ms", **{s: "kN" for s in ("F21", "F31", "Pf_tilt", "Pf_lift", "F21_x", "F21_z", "F31_x",
                                                   "F31_z", "R_x", "R_z")},
                "p_lift": "bar", "p_tilt": "bar", "x_b": "mm", "y_b": "mm", "lift_extension": "mm",
                "tilt_extension": "mm", "lift_speed": "mm/s", "tilt_speed": "mm/s", "boom_angle": "deg",
                "bucket_pitch": "deg", "travel_speed": "km/h", "m_b": "t", "m_load": "t"}
#: Units of a definite dimension, to give a column one it does not have (dimensionless ones left out: radians
#: are dimensionless for pint, so "%" would convert to an angle).
DIMENSIONS = {"kg": "kg", "mm": "m", "N": "N", "s": "s", "bar": "Pa", "m/s": "m/s", "J": "J"}
#: Unit texts no column accepts: unknown, unparseable, or that would make pint compute for ever.
ODD_UNITS = ["bananas", "kN/", "10**10**10", "N²²²²²²", "m**2**3", "N*(1/0)", "m**x", "2 kN", "((((", "m**9999",
             "1e999 N", "degC"]
#: Cells that are not numbers (none of them one of pandas' NaN spellings).
TEXTS = ["abc", "1,5", "0x1F", "12..3", "--", "1e", "∞"]
#: Huge and tiny cells, in the column's unit.
HUGE = [1e300, -1e300, 1e306, -1e306, 1.7e308, -1.7e308, 1e-300, 5e-324]
#: Command cells out of [-1, 1], and two within the reader's rounding tolerance (1e-6).
OUT_OF_RANGE = [1.5, -2.0, 40.0, 1.0 + 1e-5, 1.0 + 1e-9, -1.0 - 1e-9]
#: Extra columns: unknown ones (refused by name) and known ones the diagnosis does not compare (read, ignored).
EXTRAS = {"operator [initials]": "fails", "note": "fails", "gear [-]": "fails", "temperature [degC]": "fails",
          "fill_factor [1]": "ok", "spilled_mass [kg]": "ok", "F21_route2 [N]": "ok", "q_boom_hinge [deg]": "ok"}
#: Logs of the same episode (key → sampling rate in Hz, None = the control step; timestamp jitter in steps).
RATES: dict[str, tuple[float | None, float]] = {"control": (None, 0.0), "50 Hz": (50.0, 0.0),
                                                "100 Hz": (100.0, 0.0), "500 Hz": (500.0, 0.0),
                                                "500 Hz jittered": (500.0, 0.3), "slow": (None, 0.0)}
#: Damage done to the written file: mostly none, else one kind.
DAMAGE = st.sampled_from(["none"] * 12 + ["empty", "truncate", "not utf-8", "bom", "crlf", "semicolon", "tab"])


@dataclass(frozen=True)
class Log:
    """A log before any mutation, SI: timestamps (s), commands (rows, 3) in [-1, 1], signals, dig phases."""

    time: np.ndarray
    commands: np.ndarray
    signals: dict[str, np.ndarray]
    phases: np.ndarray

    @property
    def h(self) -> float:
        """Sampling step, s."""
        return float(np.median(np.diff(self.time)))


@dataclass(frozen=True)
class Episode:
    """The recorded episode (at the control step ``dt``, s) and its logs at every rate of :data:`RATES`."""

    dt: float
    base: Log
    logs: dict[str, Log]

    def __repr__(self) -> str:
        return f"Episode(dt={self.dt:.6g} s, {len(self.base.time)} steps, logs {list(self.logs)})"


@pytest.fixture(scope="module")
def episode() -> Episode:
    """40 control steps of the scripted dig cycle on the ``mini`` loader, logged at each rate of :data:`RATES`."""
    import gymnasium as gym

    import scaletwin_envs  # noqa: F401  (registers the env)
    from scaletwin_envs.policies.scripted import ScriptedDigPolicy
    from scaletwin_envs.recording.recorder import record_episode

    env = gym.make("WheelLoaderDig-v1", scale="mini")
    try:
        rec = record_episode(env, ScriptedDigPolicy(), seed=0, max_steps=STEPS)
    finally:
        env.close()
    data = rec.data
    assert rec.provenance.control_dt is not None
    base = Log(data["time"].to_numpy(float), rec.commands,
               {s: data[s].to_numpy(float) for s in COMPARED if s in data.columns},
               data["phase"].astype(str).to_numpy(object))
    assert all(np.isfinite(v).all() for v in base.signals.values()) and len(base.signals) == len(COMPARED)
    logs = {}
    for key, (hz, jitter) in RATES.items():
        if key == "slow":  # every other row: half the control rate, which the reader must refuse
            logs[key] = Log(base.time[::2], base.commands[::2], {k: v[::2] for k, v in base.signals.items()},
                            base.phases[::2])
        elif hz is None:
            logs[key] = base
        else:
            logs[key] = upsample(base, hz, jitter)
    return Episode(float(rec.provenance.control_dt), base, logs)


def upsample(base: Log, hz: float, jitter: float) -> Log:
    """``base`` as a logger at ``hz`` Hz sees it: signals interpolated cubically, each command held over its control
    interval ``(t_k - dt, t_k]``, the phase of that interval; inner timestamps moved by up to ±jitter/2 steps."""
    h = 1.0 / hz
    t = base.time[0] + h * np.arange(math.floor((base.time[-1] - base.time[0]) / h + 1e-9) + 1)
    t[1:-1] += jitter * h * np.random.default_rng(0).uniform(-0.5, 0.5, len(t) - 2)
    row = np.clip(np.searchsorted(base.time, t), 0, len(base.time) - 1)
    return Log(t, base.commands[row], {k: CubicSpline(base.time, v)(t) for k, v in base.signals.items()},
               base.phases[row])


def unit_of(name: str, style: str) -> tuple[str, float]:
    """The unit a ``style`` ("logger" or "SI") log writes ``name`` in, and its factor to SI."""
    si = SI_UNITS[name]
    wanted = LOGGER_UNITS.get(name, si) if style == "logger" else si
    return wanted, dict(UNITS[si])[wanted]


def log_frame(log: Log, style: str) -> pd.DataFrame:
    """``log`` as a data logger's table: ``name [unit]`` headers, values in those units, a ``phase`` column."""
    cols: dict[str, Any] = {}
    for name in ("time", *COMMAND_COLUMNS, *log.signals):
        si = log.time if name == "time" else (log.commands[:, COMMAND_COLUMNS.index(name)]
                                              if name in COMMAND_COLUMNS else log.signals[name])
        unit, factor = unit_of(name, style)
        cols[f"{name} [{unit}]"] = si / factor
    cols["phase"] = log.phases
    return pd.DataFrame(cols)


def quantity(header: str) -> str:
    """``"F21 [kN]"`` → ``"F21"``; a header without a unit is its own name."""
    return header.split("[", 1)[0].strip()


def role(name: str) -> str:
    """What a column is to the reader: ``time``, ``command``, ``signal`` or ``phase``."""
    return name if name in ("time", "phase") else "command" if name in COMMAND_COLUMNS else "signal"


@dataclass
class Case:
    """A mangled log in the making: its columns, and what reading it at the control step must give.

    ``fails`` and ``unsure`` are keyed by a column's name (``"F21"``, ``"operator"``) or ``"file"``: a refusal
    must name one of the columns keyed in either, unless ``"file"`` is among the keys.
    """

    rate: str
    fmt: str
    headers: list[str]
    cells: list[np.ndarray]  # per column: floats in the header's unit, or objects once a cell is text
    factor: dict[str, float | None]  # quantity → SI per unit of its header (None: a unit that must be refused)
    fails: dict[str, str] = field(default_factory=dict)  # → why reading must fail
    unsure: set[str] = field(default_factory=set)  # outcome not known: a read or a failure naming it are both fine
    altered: set[str] = field(default_factory=set)  # quantities whose cells or unit label changed
    si: dict[str, np.ndarray] = field(default_factory=dict)  # SI values the reader must return (NaN: bridged)
    gone: set[str] = field(default_factory=set)  # compared signals the log lacks: reported missing
    steps: list[str] = field(default_factory=list)  # what was done, in words (hypothesis prints it)
    damage: str = "none"

    def __repr__(self) -> str:
        return (f"Case({self.rate} log as {self.fmt}: {'; '.join(self.steps) or 'as recorded'}; damage "
                f"{self.damage}; must fail on {self.fails}, unsure about {sorted(self.unsure)})")

    def _repr_pretty_(self, printer: Any, cycle: bool) -> None:  # hypothesis prints falsifying examples with it
        printer.text(repr(self))

    def index(self, name: str) -> int | None:
        """The column of quantity ``name``; None once it has none (dropped, misspelt) or two (given twice): no later
        mutation touches it, so that what reading it must give stays known."""
        found = [i for i, h in enumerate(self.headers) if quantity(h) == name]
        return found[0] if len(found) == 1 else None

    def set_cell(self, i: int, row: int, value: Any) -> None:
        """Cell ``row`` of column ``i`` becomes ``value`` (the column turns to objects for a text cell)."""
        cells = self.cells[i].astype(object) if isinstance(value, str) else self.cells[i].copy()
        cells[row] = value
        self.cells[i] = cells

    def numeric(self, i: int, name: str) -> np.ndarray | None:
        """Column ``i`` in SI as the reader must see it: NaN for a CSV's empty cells; None when a cell is text."""
        cells, factor = self.cells[i], self.factor[name]
        assert factor is not None
        if cells.dtype == object:
            if any(isinstance(c, str) and (c != "" or self.fmt != "csv") for c in cells):
                return None
            cells = np.array([math.nan if isinstance(c, str) else c for c in cells], dtype=np.float64)
        with np.errstate(over="ignore"):
            return np.asarray(cells, dtype=np.float64) * factor


#: Mutations, those a reader may well survive more often than those that must be refused (about 30 % of the logs
#: are then read, enough to check what is read).
KINDS = ["unit"] * 4 + ["relabel"] * 3 + ["nan"] * 3 + ["gap"] * 4 + ["huge"] * 3 + ["range"] * 3 + ["extra"] * 3 + [
    "dimension", "odd unit", "random unit", "no unit", "drop", "twice", "again", "misspelt", "all nan", "inf", "text",
    "empty", "swap", "repeat", "jitter"]


@st.composite
def cases(draw: st.DrawFn, ep: Episode, fmt: str) -> Case:
    """A log at a drawn rate with 0–4 random mutations, and the outcome reading it must have."""
    rate = draw(st.sampled_from(["control"] * 2 + [r for r in RATES if r != "control"]))
    log = ep.logs[rate]
    frame = log_frame(log, draw(st.sampled_from(["logger", "SI"])))
    case = Case(rate, fmt, list(frame.columns), [frame[h].to_numpy() for h in frame.columns],
                {quantity(h): dict(UNITS[SI_UNITS[quantity(h)]])[h.split("[")[1][:-1]]
                 for h in frame.columns if h != "phase"})
    if rate == "slow":
        case.fails["file"] = "sampled at half the control rate"
    rows = len(log.time)
    per_step = ep.dt / log.h  # log rows per control step
    if draw(st.integers(0, 9)) == 0:  # fewer rows: too few control steps, or a shorter log that is still fine
        if draw(st.booleans()):
            rows = draw(st.integers(0, math.floor((MIN_STEPS - 0.5) * per_step)))
            case.fails["file"] = f"{rows} rows: fewer than {MIN_STEPS} control steps"
        else:
            rows = draw(st.integers(math.ceil(0.6 * rows), rows))
        case.cells = [c[:rows] for c in case.cells]
        case.steps.append(f"first {rows} rows")
    for _ in range(draw(st.sampled_from([0, 1, 1, 2, 2, 3, 4]))):  # 0–4 mutations, 1.9 on average
        kind = draw(st.sampled_from(KINDS))
        # a third of the mutations on the time or a command (the time 1 in 21: most of its faults end the read),
        # the rest on a signal or the phase
        columns, others = st.sampled_from(["time", *COMMAND_COLUMNS, *COMMAND_COLUMNS]), st.sampled_from(
            [*log.signals, "phase"])
        name = draw(columns | others | others)
        headers, cells = list(case.headers), list(case.cells)  # mutations replace arrays, never change them
        mutate(draw, case, kind, name, rows, per_step, log)
        change = describe(headers, cells, case)
        if change:
            case.steps.append(f"{kind} {name}: {change}")
    settle(case, ep.dt, log)
    return case


def mutate(draw: st.DrawFn, case: Case, kind: str, name: str, rows: int, per_step: float, log: Log) -> None:
    """Apply one mutation ``kind`` to column ``name`` (or to the time, or a new column) and note its outcome."""
    if kind in ("swap", "repeat", "jitter"):
        name = "time"
    if kind == "extra":
        header = draw(st.sampled_from(list(EXTRAS)))
        if header not in case.headers:
            case.headers.append(header)
            values = (log.signals["F21"][:rows] if header.startswith("F21") else
                      np.full(rows, "x", dtype=object) if EXTRAS[header] == "fails" else np.zeros(rows))
            case.cells.append(np.asarray(values))
            if EXTRAS[header] == "fails":
                case.fails[quantity(header)] = "an unknown column"
        return
    i = case.index(name)
    if i is None:
        return
    si_unit = SI_UNITS.get(name, "-")
    factor = case.factor.get(name)
    numeric = case.cells[i].dtype != object
    if kind in ("unit", "relabel", "dimension", "odd unit", "random unit", "no unit", "again") and name == "phase":
        return
    if kind == "unit" and name not in case.altered and factor is not None and numeric:
        unit, new = draw(st.sampled_from(UNITS[si_unit]))
        case.cells[i] = case.cells[i] * (factor / new)
        case.headers[i], case.factor[name] = f"{name} [{unit}]", new
    elif kind == "relabel" and factor is not None:  # another unit, the values not converted
        others = [u for u in UNITS[si_unit] if u[1] != factor]
        if others:
            unit, new = draw(st.sampled_from(others))
            case.headers[i], case.factor[name] = f"{name} [{unit}]", new
            case.altered.add(name)
            if name == "time":  # another time scale changes every rate and gap: anything may fail
                case.unsure.add("file")
    elif kind == "dimension":
        unit = draw(st.sampled_from([u for u, si in DIMENSIONS.items() if si != si_unit]))
        case.headers[i], case.factor[name] = f"{name} [{unit}]", None
        case.fails[name] = f"in {unit}"
    elif kind == "odd unit":
        unit = draw(st.sampled_from(ODD_UNITS))
        case.headers[i], case.factor[name] = f"{name} [{unit}]", None
        case.fails[name] = f"in {unit!r}"
    elif kind == "random unit":
        unit = draw(st.text(st.characters(blacklist_categories=("Cc", "Cs", "Zl", "Zp"),
                                          blacklist_characters='[],;\t"\'\r\n'), max_size=8))
        case.headers[i], case.factor[name] = f"{name} [{unit}]", None
        case.altered.add(name)
        case.unsure.add("file" if name == "time" else name)
    elif kind == "no unit":
        case.headers[i], case.factor[name] = name, None
        case.fails[name] = "no unit"
    elif kind == "drop":
        del case.headers[i], case.cells[i]
        if role(name) in ("time", "command"):
            case.fails[name] = "missing"
    elif kind == "twice":
        case.headers.append(case.headers[i])
        case.cells.append(case.cells[i].copy())
        case.fails[name] = "given twice"
    elif kind == "again" and factor is not None and numeric:
        unit, new = draw(st.sampled_from(UNITS[si_unit]))
        case.headers.append(f"{name} [{unit}]")
        case.cells.append(case.cells[i] * (factor / new))
        case.fails[name] = "given twice"
    elif kind == "misspelt":
        case.headers[i] = case.headers[i].replace(name, name.swapcase(), 1)
        case.fails[name] = "misspelt"
    elif kind in ("nan", "inf", "text", "empty", "huge", "range") and rows > 0:
        value = {"nan": st.just(math.nan), "inf": st.sampled_from([math.inf, -math.inf]),
                 "text": st.sampled_from(TEXTS), "empty": st.just(""), "huge": st.sampled_from(HUGE),
                 "range": st.sampled_from(OUT_OF_RANGE)}[kind]
        if kind == "range":
            if role(name) != "command" or factor is None:
                return
            value = value.map(lambda v: v / factor)
        case.set_cell(i, draw(st.integers(0, rows - 1)), draw(value))
        case.altered.add(name)
    elif kind == "gap" and rows > 1:  # a run of NaN rows, short enough to bridge or clearly too long
        short = min(max(1, math.floor(3.5 * per_step) - 1), rows - 1)
        long = min(math.ceil(5 * per_step) + 2, rows - 1)
        length = draw(st.integers(1, short) | st.integers(long, rows - 1))
        start = draw(st.integers(0, rows - length))
        cells = case.cells[i].copy()
        cells[start:start + length] = math.nan
        case.cells[i] = cells
        case.altered.add(name)
    elif kind == "all nan":
        case.cells[i] = np.full(rows, math.nan)
        case.altered.add(name)
    elif kind in ("swap", "repeat") and rows > 1 and numeric:
        row = draw(st.integers(0, rows - 2))
        cells = case.cells[i].copy()
        cells[row + 1] = cells[row]
        if kind == "swap":
            cells[row] = case.cells[i][row + 1]
        case.cells[i] = cells
        case.altered.add(name)
    elif kind == "jitter" and rows > 2 and numeric and factor is not None:
        size = draw(st.sampled_from([0.02, 0.1, 0.3])) * log.h / factor  # in steps of the log
        cells = case.cells[i].copy()
        cells[1:-1] += size * np.random.default_rng(draw(st.integers(0, 9))).uniform(-0.5, 0.5, rows - 2)
        case.cells[i] = cells
        case.altered.add(name)


def describe(headers: list[str], cells: list[np.ndarray], case: Case) -> str:
    """What a mutation changed, briefly: headers added and removed, and the first of the cells changed."""
    parts = [f"+{h!r}" for h in case.headers if h not in headers]
    parts += [f"-{h!r}" for h in headers if h not in case.headers]
    old = dict(zip(headers, cells, strict=True))
    for header, new in zip(case.headers, case.cells, strict=True):
        if header in old and len(old[header]) == len(new):
            rows = [r for r, (a, b) in enumerate(zip(old[header], new, strict=True)) if not _same(a, b)]
            if rows:
                parts.append(f"{header!r} row {rows[0]} = {new[rows[0]]!r}" + (f" ({len(rows)} rows)" if len(rows) > 1
                                                                                 else ""))
    return ", ".join(parts)


def _same(a: Any, b: Any) -> bool:
    return bool(a is b or (type(a) is type(b) and a == b)
                or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b)))


def gap_spans(time: np.ndarray, x: np.ndarray) -> list[float]:
    """Seconds without data of each run of NaN in ``x``, as the reader's documentation defines it: from the last
    sample before the run to the first after it (at an end of the log, the run's own end timestamp stands in for
    the neighbour it lacks)."""
    bad = ~np.isfinite(x)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], bad.astype(np.int8), [0]))))
    spans = []
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        before = time[start - 1] if start > 0 else time[start]
        after = time[stop] if stop < len(x) else time[stop - 1]
        spans.append(float(after - before))
    return spans


def settle(case: Case, dt: float, log: Log) -> None:
    """What the cells of the finished case make the reader do (``fails``, ``unsure``), and the SI values it must
    return (``si``): text and infinite cells and long gaps are refused by column, commands out of [-1, 1] too,
    a log without any compared signal as a whole."""
    time = None
    i = case.index("time")
    if i is not None and case.factor.get("time") is not None:
        t = case.numeric(i, "time")
        if t is None or not np.isfinite(t).all() or np.any(np.diff(t) <= 0):
            case.fails["time"] = "text, missing or not increasing"
        else:
            time = case.si["time"] = t
            if "time" in case.altered:  # jittered: uniform enough, or a dropout? left to the reader
                case.unsure.add("file")
    present = []
    for name in (*COMMAND_COLUMNS, *log.signals):
        i = case.index(name)
        if i is None or case.factor.get(name) is None:
            if name in case.unsure:
                present.append(name)
            continue
        x = case.numeric(i, name)
        if x is None or np.isinf(x).any():
            case.fails[name] = "a text or infinite cell"
            continue
        if not np.isfinite(x).any():
            if role(name) == "command":
                case.fails[name] = "no finite value"
            continue
        present.append(name)
        case.si[name] = x
        if role(name) == "command" and np.nanmax(np.abs(x)) > 1.0 + 1e-6:
            case.fails[name] = "outside [-1, 1]"
        if role(name) == "signal" and np.nanmax(np.abs(x)) > 1e250:  # may overflow a filter or a bridged line
            case.unsure.add(name)
        for span in gap_spans(time, x) if time is not None else []:
            limit = MAX_GAP_STEPS * dt
            if span > 1.05 * limit:
                case.fails[name] = f"{span:.3g} s without data"
            elif span > 0.95 * limit:
                case.unsure.add(name)
    case.gone = {s for s in log.signals if s not in present}
    if not case.gone < set(log.signals):
        case.fails["file"] = "no compared signal"


def write(case: Case, folder: Path, damage: str, cut: float) -> Path:
    """The case's columns as a file (a space in its name), damaged as asked; ``case`` learns what damage causes."""
    path = folder / f"field log.{case.fmt}"
    frame = pd.DataFrame(dict(enumerate(case.cells)))
    frame.columns = case.headers
    if case.fmt == "csv":
        sep = {"semicolon": ";", "tab": "\t"}.get(damage, ",")
        frame.to_csv(path, index=False, sep=sep, lineterminator="\r\n" if damage == "crlf" else "\n")
    else:
        import pyarrow as pa
        import pyarrow.parquet as pq

        columns = [pa.array(_storable(cells), from_pandas=True) for cells in case.cells]
        pq.write_table(pa.Table.from_arrays(columns, names=case.headers), path)
    data = path.read_bytes()
    at = int(len(data) * cut)
    if damage == "empty":
        data = b""
        case.fails["file"] = "empty"
    elif damage == "truncate":
        data = data[:at]
        if case.fmt == "parquet":
            case.fails["file"] = "truncated Parquet"
        else:  # a CSV cut at a line end is a shorter valid file; cut in a number, another number
            case.unsure.add("file")
    elif damage == "not utf-8":
        data = data[:at] + b"\xff\xfe\xfa" + data[at:]
        if case.fmt == "csv":
            case.fails["file"] = "bytes that are not UTF-8"
        else:  # Parquet's pages may be read at a wrong offset, or not at all
            case.unsure.add("file")
    elif damage == "bom":
        data = b"\xef\xbb\xbf" + data
        if case.fmt == "parquet":
            case.unsure.add("file")
    case.damage = damage
    path.write_bytes(data)
    return path


def _storable(cells: np.ndarray) -> Any:
    """A column as Arrow can store it: as it is, or as text when its cells mix types (a number and "abc")."""
    if cells.dtype != object:
        return cells
    kinds = {type(x) for x in cells if not (isinstance(x, float) and math.isnan(x))}
    return cells.tolist() if len(kinds) <= 1 else [str(x) for x in cells]


def named(column: str, message: str) -> bool:
    """Whether ``message`` names ``column`` (as a word, any case; not in the list of expected headers the importer
    appends to every message, which names every column)."""
    own = message.split("expected headers")[0]
    return re.search(rf"(?<![A-Za-z0-9_]){re.escape(column)}(?![A-Za-z0-9_])", own, flags=re.IGNORECASE) is not None


def check_refusal(exc: RecordingError, case: Case, path: Path) -> None:
    """A refusal must name the file, be expected, and name a column at fault when no file-wide cause is."""
    message = str(exc)
    assert path.name in message, message
    culprits = set(case.fails) | case.unsure
    assert culprits, f"refused a good file: {message}"
    if "file" not in culprits:
        assert any(named(c, message) for c in culprits), f"names none of {sorted(culprits)}: {message}"


def check_finite(ep: EpisodeData) -> None:
    """What every episode the reader returns must be: enough rows, increasing finite time, finite commands in
    [-1, 1], finite signals (no silent NaN)."""
    assert len(ep) >= MIN_STEPS
    assert np.isfinite(ep.time).all() and np.all(np.diff(ep.time) > 0)
    assert ep.commands.shape == (len(ep), 3) and np.isfinite(ep.commands).all()
    assert np.abs(ep.commands).max() <= 1.0 + 1e-6
    for name, values in ep.signals.items():
        assert values.shape == (len(ep),) and np.isfinite(values).all(), f"{name} is not finite"


def check_read(ep: EpisodeData, case: Case, episode: Episode) -> None:
    """An accepted log: finite, at the control step, missing channels reported, the file's values kept (at the
    control step) or close to the truth (resampled from a faster log)."""
    assert not case.fails or "file" in case.unsure, f"read although {case.fails}"
    check_finite(ep)
    dt = episode.dt
    assert abs(ep.dt - dt) <= 0.02 * dt
    if "file" in case.unsure:
        return
    assert ep.input_report is not None
    for name in case.gone - case.unsure:
        assert name not in ep.signals and name in ep.input_report.channels_missing, name
    if case.rate == "control":
        np.testing.assert_allclose(ep.time, case.si["time"], rtol=1e-9, atol=0)
        for name, x in case.si.items():
            if name == "time" or name in case.unsure:
                continue
            got = ep.commands[:, COMMAND_COLUMNS.index(name)] if name in COMMAND_COLUMNS else ep.signals[name]
            known = np.isfinite(x)  # NaN rows are bridged
            np.testing.assert_allclose(got[known], x[known], rtol=1e-9, atol=1e-290, err_msg=name)
    else:
        np.testing.assert_allclose(np.diff(ep.time), dt, rtol=1e-9)
        for name in case.si:
            if role(name) == "signal" and name not in case.altered and name not in case.unsure:
                truth = episode.base.signals[name]
                error = np.abs(ep.signals[name] - np.interp(ep.time, episode.base.time, truth)).max()
                assert error <= 0.05 * np.ptp(truth), f"{name}: off by {error:.3g} of a range {np.ptp(truth):.3g}"


def read_as_diagnose(path: Path, dt: float) -> tuple[EpisodeData | RecordingError, EpisodeData | RecordingError]:
    """What ``scaletwin diagnose PATH --twin SPEC`` makes of the file: the log at its own step (looking for a
    provenance) and at the twin's control step ``dt`` (s); each an episode or the :class:`RecordingError` raised.
    Any other exception propagates."""

    def attempt(control_dt: float | None) -> EpisodeData | RecordingError:
        try:
            return from_recording(rec, path.name, control_dt)
        except RecordingError as exc:
            return exc

    with no_hang(HANG_S):
        try:
            rec = read_log(path)
        except RecordingError as exc:
            return exc, exc
        return attempt(None), attempt(dt)


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_reader_reads_right_or_names_the_problem(fmt: str, episode: Episode,
                                                  tmp_path_factory: pytest.TempPathFactory) -> None:
    folder = tmp_path_factory.mktemp(f"logs-{fmt}")

    @settings(settings.get_profile("bad-logs"))
    @given(case=cases(episode, fmt), damage=DAMAGE, cut=st.floats(0.05, 0.95))
    def read_mangled(case: Case, damage: str, cut: float) -> None:
        path = write(case, folder, damage, cut)
        own, at_dt = read_as_diagnose(path, episode.dt)
        if isinstance(own, RecordingError):  # at its own step: a provenance or not; no other promise
            assert path.name in str(own), str(own)
        else:
            check_finite(own)
        if isinstance(at_dt, RecordingError):
            check_refusal(at_dt, case, path)
        else:
            check_read(at_dt, case, episode)
        event(f"{case.rate}: {'refused' if isinstance(at_dt, RecordingError) else 'read'}")

    read_mangled()


# -- regressions: inputs the properties found mishandled ------------------------------------------------------------

def write_log(episode: Episode, rate: str, path: Path, change: dict[str, dict[int, Any]] | None = None,
              headers: dict[str, str] | None = None, style: str = "SI") -> Path:
    """The log at ``rate`` in ``style`` units as ``path`` (CSV or Parquet), with cells changed
    (``{header: {row: value}}``, after ``headers`` renamed ``{old: new}``)."""
    frame = log_frame(episode.logs[rate], style).rename(columns=headers or {})
    for header, rows in (change or {}).items():
        cells = frame[header].to_numpy(object if any(isinstance(v, str) for v in rows.values()) else None).copy()
        for row, value in rows.items():
            cells[row] = value
        frame[header] = cells
    if path.suffix == ".csv":
        frame.to_csv(path, index=False)
    else:
        frame.to_parquet(path)
    return path


@pytest.mark.parametrize(("rate", "cells"), [
    ("500 Hz", {100: 1e306}),  # was: F21 came back inf/NaN (a silent NaN)
    ("500 Hz", {100: 1.7e308}),  # was: scipy's ValueError "`y` must contain only finite values." (no file)
    ("control", {10: 1.7e308, 11: math.nan, 12: -1.7e308}),  # was: the bridged row came back -inf
])
def test_values_that_overflow_resampling_or_bridging_are_refused_by_name(rate: str, cells: dict[int, float],
                                                                        episode: Episode, tmp_path: Path) -> None:
    path = write_log(episode, rate, tmp_path / "huge.csv", {"F21 [N]": cells})
    with pytest.raises(RecordingError, match=r"huge\.csv: F21 cannot be (resampled|bridged)"):
        load_episode(path, episode.dt)


@pytest.mark.parametrize("unit", ["((((", "m)", "1-A"])
def test_unit_pint_cannot_parse_is_refused_by_column(unit: str, episode: Episode, tmp_path: Path) -> None:
    """Was: pint's ``tokenize.TokenError`` (unbalanced brackets) or ``TypeError`` ("1-A") escaped the importer's
    report of bad columns; the file was refused as "corrupted?" without naming the column."""
    path = write_log(episode, "control", tmp_path / "units.parquet", headers={"F31 [N]": f"F31 [{unit}]"})
    with pytest.raises(RecordingError, match=r"units\.parquet") as caught:
        load_episode(path, episode.dt)
    assert "corrupted" not in str(caught.value) and f"column 'F31 [{unit}]'" in str(caught.value)


@settings(max_examples=10 * EXAMPLES, deadline=None, derandomize=EXAMPLES <= 50, database=None)
@given(unit=st.text(st.sampled_from("0123456789*^²³⁻()/+-. eEkmNAsgPa%·"), max_size=10),
       si=st.sampled_from(["N", "m", "s", "1", "rad/s^2"]))
@example(unit="((((", si="N")
@example(unit="1-A", si="1")
def test_unit_text_is_converted_or_refused_as_a_value_error(unit: str, si: str) -> None:
    """The importer's unit conversion raises only what it reports per column (ValueError, pint's errors)."""
    import pint

    from scaletwin_envs.recording.importer import to_si

    with no_hang(5), contextlib.suppress(ValueError, pint.PintError):
        assert np.isfinite(to_si(np.ones(2), unit, si)).all()


def test_command_out_of_range_is_refused_by_column(episode: Episode, tmp_path: Path) -> None:
    """Was: "commands must be normalised to [-1, 1]", without saying which of the three."""
    path = write_log(episode, "control", tmp_path / "range.csv", {"cmd_tilt [1]": {7: 40.0}})
    with pytest.raises(RecordingError, match=r"range\.csv: .*\|cmd_tilt\| is 40"):
        load_episode(path, episode.dt)


# -- the command ------------------------------------------------------------------------------------------------

def _cli_file(kind: str, episode: Episode, folder: Path) -> tuple[Path, str | None]:
    """A mangled log the reader refuses, and the column at fault (None: the file as a whole)."""
    path = folder / f"{kind}.{'parquet' if 'parquet' in kind else 'csv'}"
    if kind == "no cmd_tilt":
        write_log(episode, "control", path, style="logger")
        frame = pd.read_csv(path).drop(columns=["cmd_tilt [1]"])
        frame.to_csv(path, index=False)
        return path, "cmd_tilt"
    if kind == "text in F21":
        return write_log(episode, "100 Hz", path, {"F21 [kN]": {3: "abc"}}, style="logger"), "F21"
    if kind == "time backwards":
        time = episode.base.time
        return write_log(episode, "control", path, {"time [s]": {5: time[6], 6: time[5]}}), "time"
    if kind == "long gap in x_b parquet":
        return write_log(episode, "control", path, {"x_b [mm]": dict.fromkeys(range(10, 26), math.nan)},
                         style="logger"), "x_b"
    if kind == "cmd_lift at 40":
        return write_log(episode, "500 Hz", path, {"cmd_lift [1]": {50: 40.0}}), "cmd_lift"
    if kind == "1e306 N at 500 Hz":
        return write_log(episode, "500 Hz", path, {"F21 [N]": {300: 1e306}}), "F21"
    if kind == "unbalanced unit parquet":
        return write_log(episode, "50 Hz", path, headers={"F31 [N]": "F31 [m)]"}), "F31"
    if kind == "half rate":
        return write_log(episode, "slow", path), None
    write_log(episode, "control", path)
    data = path.read_bytes()
    damaged = {"empty": b"", "not UTF-8": data[:500] + b"\xff\xfe\xfa" + data[500:],
               "truncated parquet": data[: len(data) // 2]}[kind]
    path.write_bytes(damaged)
    return path, None


CLI_KINDS = ["no cmd_tilt", "text in F21", "time backwards", "long gap in x_b parquet", "cmd_lift at 40",
             "1e306 N at 500 Hz", "unbalanced unit parquet", "half rate", "empty", "not UTF-8", "truncated parquet"]


def test_diagnose_names_the_file_in_one_error(episode: Episode, tmp_path: Path) -> None:
    """``scaletwin diagnose LOG --twin mini`` on logs the reader refuses: exit 2, nothing on stdout, and on stderr
    the reader's message once, after ``scaletwin diagnose: error:``, naming the file (and the column at fault);
    no traceback. Only refused logs: the command cannot be stopped before the diagnosis of a good one."""
    from discrepancy.twin.spec import Simulator, TwinSpec

    assert Simulator(TwinSpec.parse("mini")).control_dt == pytest.approx(episode.dt, rel=1e-12)
    for kind in CLI_KINDS:
        path, column = _cli_file(kind, episode, tmp_path)
        with pytest.raises(RecordingError) as refused:  # the reader refuses it at the twin's control step
            load_episode(path, episode.dt)
        message = str(refused.value)
        stdout, stderr = io.StringIO(), io.StringIO()
        with no_hang(60), contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            code = main(["diagnose", str(path), "--twin", "mini", "--quiet"])
        err = stderr.getvalue()
        assert code == 2 and stdout.getvalue() == "" and "Traceback" not in err, (kind, code, err)
        assert err == f"scaletwin diagnose: error: {message}\n", (kind, err)
        assert path.name in err.splitlines()[0], (kind, err)
        assert column is None or named(column, message), (kind, message)
