"""``--law froude`` with a preset machine (issue 15): the env refuses a law with a fixed machine; the command line
says so before any simulation starts, in one line naming the options."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from scaletwin.cli import CommandError, main
from scaletwin.cli.common import check_law


def no_simulation(*args: Any, **kwargs: Any) -> Any:
    raise AssertionError("a simulation started")


@pytest.mark.parametrize(("scales", "named"), [(["mini"], "--scales mini is a preset"),
                                               (["0.3", "er12", "wa475"], "--scales er12 wa475 are presets")])
def test_dataset_refuses_froude_with_a_preset_before_simulating(scales: list[str], named: str, tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr("scaletwin_envs.recording.sweep.run_sweep", no_simulation)
    out = tmp_path / "ds"
    assert main(["dataset", str(out), "--scales", *scales, "--law", "froude", "--no-progress"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith(f"scaletwin dataset: error: --law froude applies to length ratios only, and {named}")
    assert captured.err.count("\n") == 1 and "Traceback" not in captured.err
    assert not out.exists()


def test_simulate_refuses_froude_with_a_preset(monkeypatch: pytest.MonkeyPatch,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr("gymnasium.make", no_simulation)
    assert main(["simulate", "--scale", "wa475", "--law", "froude"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("scaletwin simulate: error: --law froude applies to length ratios only, and --scale wa475 "
                          "is a preset") and err.count("\n") == 1


def test_check_law_accepts_length_ratios_and_the_default_law() -> None:
    check_law([0.3, 1.5], "froude", "--scales")
    check_law(["mini", "er12", "wa475", 0.3], "product_line", "--scales")
    with pytest.raises(CommandError, match="--scale mini is a preset"):
        check_law(["mini"], "froude", "--scale")
