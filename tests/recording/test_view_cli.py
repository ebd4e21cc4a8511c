"""``scaletwin view``: the rerun viewer command, web viewer on loopback without a display."""

from __future__ import annotations

import sys

from scaletwin.cli import main
from scaletwin.cli.view import has_display, viewer_command


def test_web_viewer_binds_to_loopback_without_display(tmp_path, monkeypatch, capsys):
    path = tmp_path / "x.rrd"
    path.write_bytes(b"")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    assert not has_display()
    assert main(["view", str(path), "--dry-run", "--port", "9111"]) == 0
    cmd = capsys.readouterr().out.split()
    assert cmd[1:4] == ["-m", "rerun", str(path)]
    assert cmd[cmd.index("--bind") + 1] == "127.0.0.1" and "--web-viewer" in cmd
    assert cmd[cmd.index("--web-viewer-port") + 1] == "9111"


def test_native_viewer_with_display(tmp_path):
    assert "--web-viewer" not in viewer_command(tmp_path / "x.rrd", web=False, port=9090)


def test_view_errors(tmp_path, capsys):
    assert main(["view", str(tmp_path / "missing.rrd")]) == 2
    (tmp_path / "x.parquet").write_bytes(b"")
    assert main(["view", str(tmp_path / "x.parquet"), "--dry-run"]) == 2
    assert "not a .rrd file" in capsys.readouterr().err
