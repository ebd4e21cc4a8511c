"""The CLI: ``scaletwin diagnose`` on a recording file (a null case, so it is quick) and its errors."""

from __future__ import annotations

import json

import pytest

from discrepancy.data.episode import to_recording
from discrepancy.report.schema import validate
from scaletwin.cli import main


def test_diagnose_cli(planted, tmp_path, capsys) -> None:
    path = to_recording(planted([]).noisy).to_parquet(tmp_path / "real.parquet")
    out = tmp_path / "d.json"
    assert main(["diagnose", str(path), "--twin", "er12:gravel:11", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    validate(doc)
    assert doc["effects"] == [] and doc["located"] == []
    bad = tmp_path / "bad.csv"
    bad.write_text("time [s],F21 [N]\n0.1,3\n")
    assert main(["diagnose", str(bad), "--twin", "er12"]) == 2
    assert "missing required columns" in capsys.readouterr().err


@pytest.mark.slow
def test_bench_cli(tmp_path) -> None:
    out, jsonl = tmp_path / "bench.md", tmp_path / "bench.jsonl"
    assert main(["bench-discrepancy", "--cases", "2", "--seed", "5", "--out", str(out), "--jsonl", str(jsonl)]) == 0
    assert "top-1 identification" in out.read_text()
    assert len(jsonl.read_text().splitlines()) == 2
