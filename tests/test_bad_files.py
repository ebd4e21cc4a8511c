"""Bad files, property-based (issue 15): mangled CSV/Parquet inputs of ``scaletwin predict`` and of its importer
(:func:`zoo.serving.read_table` + :func:`zoo.serving.inputs.to_matrix`).

Each example starts from rows of the ``ffnn-eq10`` checkpoint's check set and applies a few random mutations: a
column in another unit (values converted, so the SI values stay), a column in an impossible or random unit, a column
dropped, written twice or given again in another unit, a cell made NaN, inf, text, empty or huge, an unknown extra
column; the file is written as CSV or Parquet and may then be emptied, truncated or given bytes that are not UTF-8.
The importer must return the expected finite SI matrix or raise :class:`zoo.InputError` naming the file (never
another exception, a hang or a silent NaN); ``scaletwin predict`` must exit 0 with finite forces for every row, or
exit 2 with one error line naming the file and no traceback. Examples are few and fixed (50 per property and
format, 25 through the command) so that the module runs in seconds; ``SCALETWIN_BAD_FILES_EXAMPLES=2000`` tries
thousands of random ones.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

hypothesis = pytest.importorskip("hypothesis", reason='hypothesis is not installed (pip install -e ".[dev]")')
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

import zoo  # noqa: E402
from scaletwin.cli import main  # noqa: E402
from scaletwin_envs.recording.importer import check_unit_expression  # noqa: E402
from tests.timeouts import no_hang  # noqa: E402
from zoo.scaling_kind import check_rows  # noqa: E402
from zoo.serving import InputError, read_table  # noqa: E402
from zoo.serving.inputs import split_header, to_matrix  # noqa: E402

MODEL = "ffnn-eq10"
#: Examples per property: enough to meet every mutation many times, few enough for a few seconds
#: ($SCALETWIN_BAD_FILES_EXAMPLES tries more, e.g. 2000, with random instead of fixed examples).
EXAMPLES = int(os.environ.get("SCALETWIN_BAD_FILES_EXAMPLES", "50"))
#: Seconds one example may take before it counts as a hang.
HANG_S = 20
#: Units of the same dimension as the SI unit of each quantity, with their factor to SI.
UNITS = {"N": [("kN", 1e3), ("mN", 1e-3), ("lbf", 4.4482216152605)], "m": [("mm", 1e-3), ("cm", 1e-2), ("ft", 0.3048)],
         "kg": [("g", 1e-3), ("t", 1e3)], "m/s^2": [("mm/s**2", 1e-3), ("m/s²", 1.0)],
         "rad/s^2": [("deg/s^2", math.pi / 180)], "rad": [("deg", math.pi / 180)], "s": [("ms", 1e-3), ("min", 60.0)]}
#: Units no quantity has (furlongs: no quantity but a length), that pint cannot read, or that would make pint
#: compute for ever.
ODD_UNITS = ["furlongs", "bananas", "kN/", "10**10**10", "N²²²²²²", "m**2**3", "N*(1/0)", "m**x", "2 kN", "", "s", "[",
             "kg/", "((((", "m**9999", "1e999 N"]
BAD_CELLS = [math.nan, math.inf, -math.inf, "abc", "", "1,5", "0x1F"]
settings.register_profile("bad-files", max_examples=EXAMPLES, deadline=None, derandomize=EXAMPLES <= 50, database=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@dataclass
class Case:
    """A mangled file in the making: the frame to write, and what reading it must give."""

    frame: pd.DataFrame
    si: dict[str, np.ndarray]  # the SI values each quantity must read as
    fails: dict[str, str] = field(default_factory=dict)  # quantity (or "file") → why reading must fail
    unsure: bool = False  # a mutation whose outcome is not known (random unit text, truncated CSV): either is fine


@pytest.fixture(scope="module")
def base() -> pd.DataFrame:
    """Six check rows of the model, ``name [SI unit]`` headers, the target's quantities only (no F21)."""
    return check_rows(zoo.resolve(MODEL)[0]).drop(columns=["F21 [N]"]).head(6).reset_index(drop=True)


@pytest.fixture(scope="module")
def variables() -> tuple[str, ...]:
    return tuple(zoo.load(MODEL).target_variables)


def column_of(frame: pd.DataFrame, name: str) -> int | None:
    """The column of quantity ``name``; ``None`` once it has none (dropped) or two (given twice): no later mutation
    touches it, so that what reading it must give stays known."""
    matches = [i for i, c in enumerate(frame.columns) if split_header(c)[0] == name]
    return matches[0] if len(matches) == 1 else None


@st.composite
def cases(draw: st.DrawFn, base: pd.DataFrame, variables: tuple[str, ...]) -> Case:
    """A frame with 0–3 random mutations, and the outcome reading it must have."""
    frame = base.copy()
    si = {v: base[next(c for c in base.columns if split_header(c)[0] == v)].to_numpy(float) for v in variables}
    case = Case(frame, {k: v.copy() for k, v in si.items()})
    for _ in range(draw(st.integers(0, 3))):
        kind = draw(st.sampled_from(["unit", "odd unit", "random unit", "drop", "twice", "again", "cell", "huge",
                                     "extra"]))
        var = draw(st.sampled_from(variables))
        i = column_of(case.frame, var)
        if i is None:  # dropped or given twice by an earlier mutation
            continue
        header = case.frame.columns[i]
        name, unit = split_header(header)
        si_unit = split_header(next(c for c in base.columns if split_header(c)[0] == var))[1]
        values = case.frame.iloc[:, i]
        if kind == "unit" and unit == si_unit and si_unit in UNITS and pd.api.types.is_float_dtype(values):
            new, factor = draw(st.sampled_from(UNITS[si_unit]))
            case.frame.isetitem(i, values / factor)
            case.frame.columns = [*case.frame.columns[:i], f"{name} [{new}]", *case.frame.columns[i + 1:]]
        elif kind in ("odd unit", "random unit"):
            new = draw(st.sampled_from(ODD_UNITS) if kind == "odd unit" else
                       st.text(st.characters(blacklist_categories=("Cc", "Cs"), blacklist_characters="[]"),
                               max_size=10))
            case.frame.columns = [*case.frame.columns[:i], f"{name} [{new}]", *case.frame.columns[i + 1:]]
            if kind == "random unit" or new == unit or (new == "furlongs" and si_unit == "m"):  # a length
                case.unsure = True
            else:
                case.fails[var] = f"in {new!r}"
        elif kind == "drop":  # every column of the quantity
            case.frame = case.frame.drop(columns=[c for c in case.frame.columns if split_header(c)[0] == var])
            case.fails[var] = "missing"
        elif kind in ("twice", "again"):
            twin = header if kind == "twice" else f"{name} [{draw(st.sampled_from(UNITS[si_unit]))[0]}]"
            case.frame = pd.concat([case.frame, values.rename(twin).to_frame()], axis=1)
            case.fails[var] = "given twice"
        elif kind == "cell":
            row, bad = draw(st.integers(0, len(case.frame) - 1)), draw(st.sampled_from(BAD_CELLS))
            column = values.astype(object)
            column.iloc[row] = bad
            case.frame.isetitem(i, column)
            case.fails[var] = f"row {row} is {bad!r}"
        elif kind == "huge" and pd.api.types.is_float_dtype(values):
            row, value = draw(st.integers(0, len(case.frame) - 1)), draw(st.sampled_from([1e300, -1e300, 1e-300]))
            column = values.copy()
            column.iloc[row] = value
            case.frame.isetitem(i, column)
            factor = case.si[var][row] / values.iloc[row] if values.iloc[row] else 1.0
            case.si[var][row] = value * factor
            case.unsure = case.unsure or not math.isfinite(value * factor)
        elif kind == "extra":
            extra = draw(st.sampled_from(["operator [initials]", "gear [-]", "note", "F21_guess [kN]"]))
            if extra not in case.frame.columns:
                case.frame[extra] = draw(st.sampled_from([1.0, "x", math.nan]))
    return case


#: What happens to the written file: mostly nothing, else one of three kinds of damage.
DAMAGE = st.sampled_from(["none"] * 5 + ["empty", "truncate", "not utf-8"])


def write(case: Case, folder: Path, fmt: str, damage: str, cut: float) -> Path:
    """The case's frame as a file, damaged as asked; ``case`` learns what the damage must cause."""
    path = folder / f"target.{fmt}"
    if fmt == "csv":
        case.frame.to_csv(path, index=False)
    else:
        import pyarrow as pa
        import pyarrow.parquet as pq

        columns = [pa.array(_storable(case.frame.iloc[:, j]), from_pandas=True) for j in range(case.frame.shape[1])]
        pq.write_table(pa.Table.from_arrays(columns, names=[str(c) for c in case.frame.columns]), path)
    data = path.read_bytes()
    if damage == "empty":
        data = b""
        case.fails["file"] = "empty"
    elif damage == "truncate":
        data = data[: int(len(data) * cut)]
        if fmt == "parquet":
            case.fails["file"] = "truncated Parquet"
        else:
            case.unsure = True  # a CSV cut at a line end is a shorter valid file; cut in a number, another number
    elif damage == "not utf-8" and fmt == "csv":
        at = int(len(data) * cut)
        data = data[:at] + b"\xff\xfe\xfa" + data[at:]
        case.fails["file"] = "bytes that are not UTF-8"
    path.write_bytes(data)
    return path


def _storable(column: pd.Series) -> Any:
    """A column as Arrow can store it: as it is, or as text when its cells mix types (a number and "abc")."""
    if column.dtype != object:
        return column.to_numpy()
    kinds = {type(x) for x in column if not (isinstance(x, float) and math.isnan(x))}
    return column.tolist() if len(kinds) <= 1 else [str(x) for x in column]


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_importer_reads_right_or_names_the_problem(fmt: str, base: pd.DataFrame, variables: tuple[str, ...],
                                                   tmp_path_factory: pytest.TempPathFactory) -> None:
    folder = tmp_path_factory.mktemp(f"importer-{fmt}")

    @settings(settings.get_profile("bad-files"))
    @given(case=cases(base, variables), damage=DAMAGE, cut=st.floats(0.05, 0.95))
    def read_mangled(case: Case, damage: str, cut: float) -> None:
        path = write(case, folder, fmt, damage, cut)
        try:
            with no_hang(HANG_S):
                matrix = to_matrix(read_table(path), variables, str(path))
        except InputError as exc:
            message = str(exc)
            assert str(path) in message, message
            assert case.fails or case.unsure, f"refused a good file: {message}"
            return
        assert case.unsure or not case.fails, f"read although {case.fails}"
        assert matrix.shape[1] == len(variables) and np.isfinite(matrix).all()
        if not case.unsure:
            expected = np.column_stack([case.si[v] for v in variables])
            np.testing.assert_allclose(matrix, expected, rtol=1e-9, atol=0)

    read_mangled()


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_predict_answers_or_names_the_file(fmt: str, base: pd.DataFrame, variables: tuple[str, ...],
                                           tmp_path_factory: pytest.TempPathFactory) -> None:
    """``scaletwin predict`` in this process: exit 0 and a finite force per row, or exit 2 and one error line."""
    folder = tmp_path_factory.mktemp(f"predict-{fmt}")
    out = folder / "scaled.csv"

    @settings(settings.get_profile("bad-files"), max_examples=EXAMPLES // 2)
    @given(case=cases(base, variables), damage=DAMAGE, cut=st.floats(0.05, 0.95))
    def predict_mangled(case: Case, damage: str, cut: float) -> None:
        path = write(case, folder, fmt, damage, cut)
        out.unlink(missing_ok=True)
        stdout, stderr = io.StringIO(), io.StringIO()
        with no_hang(HANG_S), contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            code = main(["predict", "--model", MODEL, "--target", str(path), "--out", str(out)])
        err = stderr.getvalue()
        assert "Traceback" not in err
        if code == 0:
            assert case.unsure or not case.fails, f"predicted although {case.fails}"
            force = pd.read_csv(out)["F21 [N]"]
            assert len(force) == len(pd.read_csv(path) if fmt == "csv" else pd.read_parquet(path))
            assert np.isfinite(force).all()
            return
        errors = [line for line in err.splitlines() if not line.startswith("scaletwin predict: warning: ")]
        assert code == 2 and len(errors) == 1, err
        assert errors[0].startswith(f"scaletwin predict: error: target {path}"), errors[0]
        assert case.fails or case.unsure or "non-finite" in errors[0], f"refused a good file: {errors[0]}"

    predict_mangled()


@settings(max_examples=200, deadline=None, derandomize=True, database=None)
@given(unit=st.text(st.sampled_from("0123456789*^²³⁴⁻()/ .eNmk"), max_size=16))
def test_unit_text_never_hangs_the_converter(unit: str) -> None:
    """Exponent towers are refused before pint evaluates them; whatever passes converts (or not) at once."""
    from zoo.serving.inputs import unit_factor

    with no_hang(5):
        try:
            check_unit_expression(unit)
        except ValueError:
            return
        with contextlib.suppress(InputError):
            unit_factor("F31", unit)
