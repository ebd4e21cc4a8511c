"""``scaletwin predict`` and ``scaletwin zoo list|show`` on the shipped δ1 checkpoints."""

from __future__ import annotations

import io
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import zoo
from scaletwin.cli import main
from zoo.scaling_kind import check_rows


@pytest.fixture(scope="module")
def check() -> pd.DataFrame:
    return check_rows(zoo.resolve("ffnn-eq10")[0])


def _target_file(check: pd.DataFrame, path: Path) -> Path:
    """The check rows without F21, forces in kN and lengths in mm (as a user's log might be)."""
    frame = check.drop(columns=["F21 [N]"])
    for col in ("F31", "Pf_tilt", "Pf_lift"):
        frame[f"{col} [kN]"] = frame.pop(f"{col} [N]") / 1e3
    for col in ("x_b", "y_b"):
        frame[f"{col} [mm]"] = frame.pop(f"{col} [m]") * 1e3
    if path.suffix == ".parquet":
        frame.to_parquet(path, index=False)
    else:
        frame.to_csv(path, index=False)
    return path


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_predict_writes_force_and_interval(check: pd.DataFrame, tmp_path: Path, suffix: str):
    target = _target_file(check, tmp_path / f"target{suffix}")
    out = tmp_path / f"scaled{suffix}"
    assert main(["predict", "--model", "ffnn-eq10", "--target", str(target), "--out", str(out)]) == 0
    result = pd.read_parquet(out) if suffix == ".parquet" else pd.read_csv(out)
    assert list(result.columns) == ["machine", "episode", "t [s]", "F21 [N]", "F21_lower [N]", "F21_upper [N]",
                                    "delta1 [1]", "extrapolated"]
    expected = zoo.load("ffnn-eq10").scale_force(None, check.drop(columns=["F21 [N]"]))
    np.testing.assert_allclose(result["F21 [N]"], expected.force, rtol=1e-9)
    assert np.all(result["F21_lower [N]"] <= result["F21 [N]"])
    assert np.all(result["F21 [N]"] <= result["F21_upper [N]"])


def test_predict_with_source_file_and_stdout(check: pd.DataFrame, tmp_path: Path):
    model = zoo.load("ffnn-eq10")
    source = tmp_path / "source.csv"
    pd.DataFrame([{f"{k} [N]" if k in ("F21", "F31", "Pf_tilt", "Pf_lift") else k: model.reference[k]
                   for k in model.source_variables}] * 3).to_csv(source, index=False)
    target = _target_file(check.head(10), tmp_path / "target.csv")
    buf = io.StringIO()
    with redirect_stdout(buf):
        assert main(["predict", "--model", "ffnn-eq10", "--target", str(target), "--source", str(source),
                     "--source-row", "1"]) == 0
    result = pd.read_csv(io.StringIO(buf.getvalue()))
    np.testing.assert_allclose(result["F21 [N]"], model.scale_force(None, check.head(10)).force, rtol=1e-9)


def test_predict_picks_the_source_row_closest_to_the_reference(check: pd.DataFrame, tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]):
    model = zoo.load("ffnn-eq10")
    ref = {k: model.reference[k] for k in model.source_variables}
    rows = [{k: v * (1.2 if k == "Pf_tilt" else 1.0) for k, v in ref.items()}, ref, {**ref, "F21": ref["F21"] * 0.9}]
    source = tmp_path / "er12.csv"
    pd.DataFrame(rows * 2).iloc[:5].to_csv(source, index=False)
    target = _target_file(check.head(7), tmp_path / "target.csv")
    out = tmp_path / "out.csv"
    assert main(["predict", "--model", "ffnn-eq10", "--target", str(target), "--source", str(source), "--out",
                 str(out)]) == 0
    assert "source row 1 of 5" in capsys.readouterr().err
    np.testing.assert_allclose(pd.read_csv(out)["F21 [N]"], model.scale_force(None, check.head(7)).force, rtol=1e-9)


def test_predict_errors_are_one_line(check: pd.DataFrame, tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    target = tmp_path / "bad.csv"
    check.drop(columns=["F21 [N]", "Pf_lift [N]"]).to_csv(target, index=False)
    assert main(["predict", "--model", "ffnn-eq10", "--target", str(target)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"scaletwin predict: error: target {target}: missing quantities: Pf_lift [N]")
    assert "Traceback" not in err
    assert main(["predict", "--model", "bucketfill-ppo", "--target", str(target)]) == 2
    assert "not a scaling model" in capsys.readouterr().err
    assert main(["predict", "--model", "nope", "--target", str(target)]) == 2
    assert "neither a registered checkpoint" in capsys.readouterr().err


def test_zoo_list_and_show(capsys: pytest.CaptureFixture[str]):
    assert main(["zoo", "list", "--kind", "scaling-model"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in ("ffnn-eq10", "gru-eq10", "gru-eq23", "ffnn-pose", "ensemble-eq10"))
    assert main(["zoo", "show", "gru-eq23", "--verify"]) == 0
    out = capsys.readouterr().out
    assert "verified" in out and "F21/F31" in out and "held_out" in out
    assert main(["zoo", "show", "statics-pl", "--verify"]) == 0
    out = capsys.readouterr().out
    assert "verified" in out and "F21/F21_linkage" in out and "direct-Pi" in out and "wa475" in out
    assert "read off the interval" in out and "AUROC" in out  # the served risk and how it did on held-out machines
