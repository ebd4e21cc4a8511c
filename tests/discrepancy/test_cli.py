"""The CLI: ``scaletwin diagnose`` on a recording file (a null case, so it is quick) and its errors."""

from __future__ import annotations

import dataclasses
import json
import re

import pytest

import discrepancy
from discrepancy import ReportedEffect
from discrepancy.data.episode import to_recording
from discrepancy.report.schema import validate
from scaletwin.cli import main

STEPS = ("load", "align", "replay", "null", "locate", "redundancy", "identify", "fit", "compare", "done")
LABELS = ["viscous_damping[tilt_barrel_hinge]", "coulomb_friction[lift_cylinder]", "viscous_damping[bell_crank_hinge]",
          "coulomb_friction[tilt_cylinder]"]


def test_diagnose_cli(planted, tmp_path, capsys) -> None:
    path = to_recording(planted([]).noisy).to_parquet(tmp_path / "real.parquet")
    out = tmp_path / "d.json"
    assert main(["diagnose", str(path), "--twin", "er12:gravel:11", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    validate(doc)
    assert doc["effects"] == [] and doc["located"] == []
    assert doc["fit"]["flags"] == {} and not doc["fit"]["worse_overall"] and doc["fit"]["held_out"] is False
    captured = capsys.readouterr()
    progress = re.findall(r"^\[\s*(\d+\.\d) s\] (\w+)$", captured.err, flags=re.M)
    assert [step for _, step in progress] == list(STEPS)  # one line per step, in order, with elapsed seconds
    assert [float(t) for t, _ in progress] == sorted(float(t) for t, _ in progress)
    assert "No effect named: nothing differs beyond noise." in captured.out and "[" not in captured.out[:1]
    bad = tmp_path / "bad.csv"
    bad.write_text("time [s],F21 [N]\n0.1,3\n")
    assert main(["diagnose", str(bad), "--twin", "er12"]) == 2
    assert "missing required columns" in capsys.readouterr().err


def test_diagnose_cli_prints_full_labels_quietly(planted, tmp_path, capsys, monkeypatch) -> None:
    """At 80 columns every effect's full target, interval, unit and rivals' labels are printed; ``--quiet``
    leaves stderr empty."""
    real_diagnose = discrepancy.diagnose

    def with_effects(*args, **kwargs):
        d = real_diagnose(*args, **kwargs)
        named = ReportedEffect("coulomb_friction", "lift_barrel_hinge", {"friction": 1234.5},
                               {"friction": (1100.0, 1400.0)}, {"pi_friction": 0.0125}, 0.97, LABELS[:3],
                               explained_fraction=0.93, alternatives=[LABELS[3]])
        rest = ReportedEffect("unexplained", "F21", {}, {}, {}, None, LABELS, explained_fraction=0.4)
        return dataclasses.replace(d, effects=[named, rest])

    monkeypatch.setattr(discrepancy, "diagnose", with_effects)
    monkeypatch.setenv("COLUMNS", "80")
    path = to_recording(planted([]).noisy).to_parquet(tmp_path / "real.parquet")
    out = tmp_path / "d.json"
    assert main(["diagnose", str(path), "--twin", "er12:gravel:11", "--quiet", "--json", str(out)]) == 0
    captured = capsys.readouterr()
    assert captured.err == ""
    lines = captured.out.splitlines()
    assert max(len(line) for line in lines) <= 80
    for label in LABELS:
        assert any(label in line for line in lines), label
    assert "1. coulomb_friction on lift_barrel_hinge" in captured.out
    assert "friction = 1234 N*m, 95 % interval [1100, 1400]" in captured.out
    assert "cannot be told apart from: coulomb_friction[tilt_cylinder]" in captured.out
    assert "2. unexplained, shows most on F21" in captured.out and "confidence —" in captured.out
    effects = json.loads(out.read_text())["effects"]
    assert effects[1]["confidence"] is None and effects[1]["explained_fraction"] == 0.4
    assert effects[0]["alternatives"] == [LABELS[3]]


@pytest.mark.parametrize(("cores", "flag", "expected"), [(2, [], 2), (64, [], 8), (None, [], 1),
                                                           (64, ["--workers", "1"], 1), (2, ["--workers", "3"], 3)])
def test_diagnose_uses_every_core_by_default(planted, tmp_path, monkeypatch, cores, flag, expected) -> None:
    """Without ``--workers`` the replays run in one process per core (at most MAX_DEFAULT_WORKERS); ``--workers``
    overrides it."""
    from scaletwin.cli import diagnose as cli_diagnose

    seen = {}

    def capture(real, twin, held_out=(), options=None):
        seen["workers"] = options.workers
        raise discrepancy.RecordingError("stop here")

    monkeypatch.setattr(discrepancy, "diagnose", capture)
    monkeypatch.setattr(cli_diagnose.os, "cpu_count", lambda: cores)
    path = to_recording(planted([]).noisy).to_parquet(tmp_path / "real.parquet")
    assert main(["diagnose", str(path), "--twin", "er12:gravel:11", "--quiet", *flag]) == 2
    assert seen["workers"] == expected
    assert cli_diagnose.MAX_DEFAULT_WORKERS == 8


@pytest.mark.slow
def test_bench_cli(tmp_path) -> None:
    out, jsonl = tmp_path / "bench.md", tmp_path / "bench.jsonl"
    assert main(["bench-discrepancy", "--cases", "2", "--seed", "5", "--out", str(out), "--jsonl", str(jsonl)]) == 0
    assert "top-1 identification" in out.read_text()
    assert len(jsonl.read_text().splitlines()) == 2
