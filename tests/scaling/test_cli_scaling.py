"""The scaling commands: ``scaletwin fit``, ``validate-mini``, ``demo`` and ``reproduce`` (full run: slow)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from scaletwin.cli import build_parser, main
from scaling.data import DatasetSpec, generate_recordings

MICRO = DatasetSpec(soils=("gravel",), pile_heights=(0.7,), dig_seeds=2, hold_episodes=1, hold_poses=2)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return generate_recordings(MICRO, tmp_path_factory.mktemp("data"), executor="serial", progress=False)


@pytest.fixture(scope="module")
def fitted(recordings: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("fit")
    code = main(["fit", "--data", str(recordings), "--no-held-out", "--models",
                 "ffnn,power-law,direct-pi", "--epochs", "30", "--out", str(out), "--no-rerun"])
    assert code == 0
    return out


def test_commands_are_registered() -> None:
    text = build_parser().format_help()
    for command in ("fit", "validate-mini", "reproduce", "demo"):
        assert command in text


def test_fit_writes_models_metrics_and_provenance(fitted: Path) -> None:
    metrics = json.loads((fitted / "metrics.json").read_text())
    assert set(metrics["models"]) == {"ffnn", "power-law", "direct-pi"}
    prov = json.loads((fitted / "provenance.json").read_text())
    assert prov["kind"] == "run" and prov["data_hashes"]["train"] and prov["params"]["seed"] == 0
    assert (fitted / "models" / "ffnn" / "weights.safetensors").is_file()


def test_validate_mini_json_schema(fitted: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out_json, png = tmp_path / "mini.json", tmp_path / "mini.png"
    assert main(["validate-mini", str(fitted), "--json", str(out_json), "--figure", str(png)]) == 0
    payload = json.loads(out_json.read_text())
    assert set(payload) == {"loads_kg", "models"}
    assert payload["loads_kg"] == pytest.approx(list(np.linspace(0.5, 4.0, 8)))
    assert "direct-pi" in payload["models"] and "ffnn" in payload["models"]
    for entry in payload["models"].values():
        assert set(entry) == {"mean_abs_pct_error", "pct_error"}
        assert len(entry["pct_error"]) == 8 and all(np.isfinite(entry["pct_error"]))
        assert entry["mean_abs_pct_error"] == pytest.approx(np.mean(np.abs(entry["pct_error"])))
    assert png.is_file() and png.stat().st_size > 1000
    assert "direct-pi" in capsys.readouterr().out


def test_validate_mini_errors_are_user_facing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["validate-mini", str(tmp_path / "nope")]) == 2
    assert "scaletwin fit" in capsys.readouterr().err


def test_demo_on_tiny_settings(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import scaletwin.cli.demo as demo

    monkeypatch.setattr(demo, "DEMO", MICRO)
    monkeypatch.setattr(demo, "DEMO_MODELS", tuple(replace(s, config={**s.config, "epochs": 20})
                                                   if "epochs" in s.config else s for s in demo.DEMO_MODELS))
    assert main(["demo", "--out", str(tmp_path), "--no-rerun"]) == 0
    for name in ("mini.json", "mini.png", "pred_vs_actual_ffnn.png", "run/metrics.json", "run/provenance.json"):
        assert (tmp_path / name).is_file(), name
    assert set(json.loads((tmp_path / "mini.json").read_text())["models"]) == {"ffnn", "direct-pi"}


def test_reproduce_quick_writes_the_report(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import scaling.reproduce as rep

    monkeypatch.setattr(rep, "QUICK", replace(rep.QUICK, train=MICRO, reference_draws=1,
                                              held_out=replace(rep.QUICK.held_out, dig_seeds=1)))
    assert main(["reproduce", "--quick", "--out", str(tmp_path), "--workers", "serial", "--no-rerun"]) == 0
    report = (tmp_path / "report.md").read_text()
    assert "| paper | ours |" in report and "Fig. 12" in report and "direct-pi" in report
    assert (tmp_path / "figures" / "error_vs_load.png").is_file()
    assert (tmp_path / "grid" / "results.csv").is_file()


@pytest.mark.slow
def test_full_reproduction(tmp_path: Path) -> None:
    """The paper's results end to end on the standard data set (about 20 minutes on two cores)."""
    assert main(["reproduce", "--out", str(tmp_path)]) == 0
    report = (tmp_path / "report.md").read_text()
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["models"]["ffnn"]["r2_dig"] > 0.95
    assert metrics["mini"]["models"]["ffnn"]["mean_abs_pct_error"] < 5.0
    assert metrics["models"]["ffnn-pose"]["r2_dig"] >= 0.99  # issue 5's FFNN target, with the pose groups
    assert metrics["mini"]["models"]["ffnn-pose"]["mean_abs_pct_error"] <= 2.0
    assert min(metrics["models"]["gru-eq10"]["r2_dig"], metrics["models"]["gru-eq23"]["r2_dig"]) >= 0.95
    assert "## Targets" in report
