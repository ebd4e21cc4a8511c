"""How the ``scaletwin`` command line behaves as a program (issue 15, "Command line"): help without heavy imports,
quiet ends when the reader of stdout goes away, honest counts, checked units, named files, explained outputs."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import zoo
from scaletwin.cli import BROKEN_PIPE_EXIT, main
from scaletwin.cli.simulate import success_line
from zoo.scaling_kind import check_rows

ROOT = Path(__file__).resolve().parents[1]
#: Top-level packages that registering the commands must not import (each costs 0.05–3 s; torch and scaling most).
HEAVY = ("numpy", "pandas", "pyarrow", "torch", "mujoco", "gymnasium", "matplotlib", "scipy", "sympy", "pint",
         "rich", "rerun", "tqdm", "scaling", "zoo", "scaletwin_envs", "discrepancy")
#: Builds the parser, prints every subcommand's help, then the loaded top-level packages as JSON (on stderr).
PARSER_IMPORTS = """
import contextlib, io, json, sys
from scaletwin.cli import build_parser, main
parser = build_parser()
commands = sorted(parser._subparsers._group_actions[0].choices)
for argv in ([], *([c] for c in commands), ["zoo", "list"], ["zoo", "build"]):
    with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
        main([*argv, "--help"])
print(json.dumps({"commands": commands, "modules": sorted({m.split(".")[0] for m in sys.modules})}), file=sys.stderr)
"""


def run_python(code: str, env: dict[str, str] | None = None,
               stdout: int = subprocess.PIPE) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, stdout=stdout, stderr=subprocess.PIPE,
                          text=True, timeout=300, check=False)


def python_env(unbuffered: bool) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    if unbuffered:
        env["PYTHONUNBUFFERED"] = "1"
    return env


# -- scaletwin --help ------------------------------------------------------------------------------------------
def test_help_of_every_command_imports_nothing_heavy() -> None:
    out = run_python(PARSER_IMPORTS)
    assert out.returncode == 0, out.stderr
    loaded = json.loads(out.stderr.strip().splitlines()[-1])
    assert {"demo", "fit", "predict", "simulate", "dataset", "zoo", "diagnose"} <= set(loaded["commands"])
    assert sorted(set(loaded["modules"]) & set(HEAVY)) == []


def test_light_constants_agree_with_the_packages() -> None:
    """Registering ``fit`` spells out the presets and model names so as not to import :mod:`scaling`."""
    from scaletwin.cli import build_parser
    from scaletwin.cli.fit import DATASET_PRESETS, MODEL_NAMES
    from scaletwin_envs.evaluation import DEFAULT_SCALES, DEFAULT_SOILS
    from scaling.data.recordings import PRESETS
    from scaling.runs.pipeline import DEFAULT_MODELS

    assert tuple(sorted(PRESETS)) == DATASET_PRESETS
    assert tuple(s.name for s in DEFAULT_MODELS) == MODEL_NAMES
    sub = build_parser()._subparsers._group_actions[0].choices
    help_text = " ".join(sub["evaluate-policy"].format_help().split())
    assert f"default {','.join(map(str, DEFAULT_SCALES))})" in help_text
    assert f"default {','.join(DEFAULT_SOILS)})" in help_text


# -- a reader that goes away -----------------------------------------------------------------------------------
@pytest.mark.parametrize(("argv", "unbuffered"), [
    pytest.param(argv, unbuffered, id=f"{' '.join(argv)}-{'unbuffered' if unbuffered else 'buffered'}")
    for argv in (["--version"], ["--help"], ["view", "{rrd}", "--dry-run"]) for unbuffered in (False, True)
] + [pytest.param(["zoo", "list"], False, id="zoo list-buffered")])  # rich handles an unbuffered broken pipe itself
def test_closed_stdout_ends_quietly(argv: list[str], unbuffered: bool, tmp_path: Path) -> None:
    """stdout is a pipe whose reader has already gone: no traceback, no "Exception ignored", a conventional code."""
    rrd = tmp_path / "x.rrd"
    rrd.write_bytes(b"")
    argv = [a.format(rrd=rrd) for a in argv]
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        out = run_python(f"from scaletwin.cli import main; raise SystemExit(main({argv!r}))",
                         env=python_env(unbuffered), stdout=write_end)
    finally:
        os.close(write_end)
    assert out.stderr == ""
    if unbuffered and argv[0] in ("--help", "--version"):
        assert out.returncode == 0  # argparse itself ignores a failed write of its messages when unbuffered
    else:
        assert out.returncode == BROKEN_PIPE_EXIT


@pytest.fixture(scope="module")
def check() -> pd.DataFrame:
    """The ffnn-eq10 checkpoint's check rows (``name [unit]`` headers, SI), F21 included."""
    return check_rows(zoo.resolve("ffnn-eq10")[0])


def test_predict_into_head_ends_quietly(check: pd.DataFrame, tmp_path: Path) -> None:
    """``scaletwin predict ... | head -3``: the output (MBs) is far larger than a pipe's buffer."""
    target = tmp_path / "target.csv"
    pd.concat([check.drop(columns=["F21 [N]"])] * 100, ignore_index=True).to_csv(target, index=False)
    errors = tmp_path / "stderr.txt"
    code = "from scaletwin.cli import main; raise SystemExit(main(['predict', '--model', 'ffnn-eq10', '--target', " \
           f"{str(target)!r}]))"
    with errors.open("w") as err:
        proc = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, env=python_env(False),
                                stdout=subprocess.PIPE, stderr=err, text=True)
        assert proc.stdout is not None
        head = [proc.stdout.readline() for _ in range(3)]
        proc.stdout.close()
        assert proc.wait(timeout=300) == BROKEN_PIPE_EXIT
    assert head[0].startswith("machine,episode,t [s],F21 [N]") and all(line.endswith("\n") for line in head)
    assert errors.read_text() == ""


# -- scaletwin dataset -----------------------------------------------------------------------------------------
def test_dataset_does_not_count_failures_as_recorded(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["dataset", str(tmp_path / "bad"), "--scales", "-1", "--no-progress"]) == 1
    out = capsys.readouterr().out
    assert ": 0 recorded, 0 already present, 1 failed" in out and "scale must be" in out
    assert main(["dataset", str(tmp_path / "mixed"), "--scales", "mini", "-1", "--no-progress"]) == 1
    assert ": 1 recorded, 0 already present, 1 failed" in capsys.readouterr().out
    assert len(list((tmp_path / "mixed").glob("ep-*.parquet"))) == 1
    assert main(["dataset", str(tmp_path / "mixed"), "--scales", "mini", "-1", "--no-progress"]) == 1
    assert ": 0 recorded, 1 already present, 1 failed" in capsys.readouterr().out


# -- scaletwin predict: units and damaged files ----------------------------------------------------------------
def _predict(target: Path, *extra: str) -> int:
    return main(["predict", "--model", "ffnn-eq10", "--target", str(target), *extra])


@pytest.mark.parametrize("header", ["F21 [furlongs]", "p_lift [kg]", "time [bananas]", "F31 [kN/]"])
def test_predict_rejects_a_known_quantity_in_a_wrong_unit(check: pd.DataFrame, tmp_path: Path, header: str,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """Whether or not the model reads the column (F21 and p_lift it does not)."""
    name = header.split(" [")[0]
    frame = check.drop(columns=["F21 [N]"]).copy()
    if name == "F31":
        frame[header] = frame.pop("F31 [N]") / 1e3
    else:
        frame[header] = 1.0
    target = tmp_path / "target.csv"
    frame.to_csv(target, index=False)
    assert _predict(target) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    err = captured.err.strip()
    assert err.startswith(f"scaletwin predict: error: target {target}: column {header!r}: unit ")
    assert f"is not a unit of {name}" in err and "\n" not in err


def test_predict_checks_the_source_file_too(check: pd.DataFrame, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    target, source = tmp_path / "target.csv", tmp_path / "er12.csv"
    check.drop(columns=["F21 [N]"]).to_csv(target, index=False)
    check.head(1).rename(columns={"x_b [m]": "x_b [s]"}).to_csv(source, index=False)
    assert _predict(target, "--source", str(source)) == 2
    assert f"error: source {source}: column 'x_b [s]'" in capsys.readouterr().err


def test_predict_warns_about_an_unknown_column_in_an_unknown_unit(check: pd.DataFrame, tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    plain, odd = tmp_path / "plain.csv", tmp_path / "odd.csv"
    frame = check.drop(columns=["F21 [N]"])
    frame.to_csv(plain, index=False)
    frame.assign(**{"operator [initials]": 7, "gear [-]": 2}).to_csv(odd, index=False)
    assert _predict(plain, "--out", str(tmp_path / "plain_out.csv")) == 0
    capsys.readouterr()
    assert _predict(odd, "--out", str(tmp_path / "odd_out.csv")) == 0
    err = capsys.readouterr().err
    assert f"warning: target {odd}: column 'operator [initials]': pint does not know the unit 'initials'" in err
    assert "gear" not in err  # a known unit on an unknown column is fine
    np.testing.assert_array_equal(pd.read_csv(tmp_path / "odd_out.csv")["F21 [N]"],
                                  pd.read_csv(tmp_path / "plain_out.csv")["F21 [N]"])


@pytest.mark.parametrize("damage", ["truncated parquet", "empty csv", "binary csv"])
def test_predict_names_a_file_it_cannot_read(check: pd.DataFrame, tmp_path: Path, damage: str,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    good = tmp_path / "good.parquet"
    check.drop(columns=["F21 [N]"]).to_parquet(good, index=False)
    if damage == "truncated parquet":
        target = tmp_path / "cut.parquet"
        target.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    elif damage == "empty csv":
        target = tmp_path / "empty.csv"
        target.write_bytes(b"")
    else:
        target = tmp_path / "binary.csv"
        target.write_bytes(good.read_bytes())
    assert _predict(target) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"scaletwin predict: error: target {target}: cannot read the file (")
    assert "\n" not in err


# -- scaletwin simulate and demo -------------------------------------------------------------------------------
def test_success_line_names_the_criteria_and_what_was_missed() -> None:
    base = {"success": False, "fill_factor": 0.5, "cycle_time": 3.0, "sim_error": None}
    assert success_line({**base, "success": True, "fill_factor": 0.9}, 0.85, 11.0).startswith(
        "success True: the cycle completed with fill factor 0.9 >= 0.85. A dig succeeds when")
    assert success_line(base, 0.85, 11.0).startswith("success False: fill factor 0.5 < 0.85. ")
    timed_out = success_line({**base, "cycle_time": 11.0, "fill_factor": 0.9}, 0.85, 11.0)
    assert timed_out.startswith("success False: the cycle did not complete within the time limit of 11 s. ")
    assert success_line({**base, "sim_error": "non-finite signals"}, 0.85, 11.0).startswith(
        "success False: the simulation failed (non-finite signals) and fill factor 0.5 < 0.85. ")
    assert "fill factor (load / heaped bucket volume) of at least 0.85" in timed_out


def test_simulate_explains_success(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    kpis_file = tmp_path / "kpis.json"
    main(["simulate", "--scale", "mini", "--json", str(kpis_file)])
    out = " ".join(capsys.readouterr().out.split())  # rich wraps lines at the terminal's width
    kpis = json.loads(kpis_file.read_text())["kpis"]
    assert f"success {kpis['success']}: " in out
    assert "A dig succeeds when its cycle completes" in out and "of at least 0.85." in out


def test_demo_output_folder_is_ignored_by_git() -> None:
    from scaletwin.cli.demo import DEFAULT_OUT

    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    probe = subprocess.run(["git", "check-ignore", "-q", f"{DEFAULT_OUT}/run/metrics.json"], cwd=ROOT, check=False)
    assert probe.returncode == 0
