"""``scaletwin view``: the rerun viewer command, web viewer on loopback without a display, with an address that
opens the recording, two configurable ports (free ones when the defaults are taken) and the ports to forward."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from urllib.parse import parse_qs, urlparse

import pytest

from scaletwin.cli import main
from scaletwin.cli import view as view_cli
from scaletwin.cli.view import has_display, viewer_command, viewer_url


@pytest.fixture
def headless(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")


@pytest.fixture
def rrd(tmp_path):
    path = tmp_path / "x.rrd"
    path.write_bytes(b"")
    return path


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_web_viewer_binds_to_loopback_and_prints_the_recording_address(headless, rrd, capsys):
    assert not has_display()
    http, grpc = _free_port(), _free_port()
    assert main(["view", str(rrd), "--dry-run", "--port", str(http), "--grpc-port", str(grpc)]) == 0
    out = capsys.readouterr().out.splitlines()
    cmd = out[0].split()
    assert cmd[1:4] == ["-m", "rerun", str(rrd)]
    assert cmd[cmd.index("--bind") + 1] == "127.0.0.1" and "--web-viewer" in cmd
    assert cmd[cmd.index("--web-viewer-port") + 1] == str(http) and cmd[cmd.index("--port") + 1] == str(grpc)
    text = "\n".join(out[1:])
    url = text.split("open ", 1)[1].split()[0]
    assert url == viewer_url(http, grpc)
    parsed = urlparse(url)
    assert (parsed.hostname, parsed.port) == ("127.0.0.1", http)
    assert parse_qs(parsed.query)["url"] == [f"rerun+http://127.0.0.1:{grpc}/proxy"]  # the page opens the recording
    assert f"ssh -L {http}:127.0.0.1:{http} -L {grpc}:127.0.0.1:{grpc}" in text  # what a remote user forwards


def test_native_viewer_with_display(tmp_path):
    cmd = viewer_command(tmp_path / "x.rrd", web=False, port=9090)
    assert "--web-viewer" not in cmd and "--port" not in cmd


def test_taken_default_ports_move_to_free_ones(headless, rrd, capsys, monkeypatch):
    with socket.socket() as a, socket.socket() as b:  # another viewer holds the defaults
        a.bind(("127.0.0.1", 0))
        b.bind(("127.0.0.1", 0))
        a.listen()
        b.listen()
        taken_http, taken_grpc = a.getsockname()[1], b.getsockname()[1]
        monkeypatch.setattr(view_cli, "DEFAULT_HTTP_PORT", taken_http)
        monkeypatch.setattr(view_cli, "DEFAULT_GRPC_PORT", taken_grpc)
        assert main(["view", str(rrd), "--dry-run"]) == 0
        cmd = capsys.readouterr().out.splitlines()[0].split()
        http, grpc = int(cmd[cmd.index("--web-viewer-port") + 1]), int(cmd[cmd.index("--port") + 1])
        assert http != taken_http and grpc != taken_grpc and http != grpc
        # a port asked for explicitly is not moved: a clear error instead
        assert main(["view", str(rrd), "--dry-run", "--port", str(taken_http)]) == 2
        assert "in use" in capsys.readouterr().err
    assert main(["view", str(rrd), "--dry-run", "--port", "9111", "--grpc-port", "9111"]) == 2
    assert "must differ" in capsys.readouterr().err
    assert main(["view", str(rrd), "--dry-run", "--grpc-port", "70000"]) == 2


def test_view_errors(tmp_path, capsys):
    assert main(["view", str(tmp_path / "missing.rrd")]) == 2
    (tmp_path / "x.parquet").write_bytes(b"")
    assert main(["view", str(tmp_path / "x.parquet"), "--dry-run"]) == 2
    assert "not a .rrd file" in capsys.readouterr().err


def _start_viewer(path, http: int, grpc: int) -> subprocess.Popen:
    code = f"from scaletwin.cli import main; raise SystemExit(main(['view', {str(path)!r}, '--web', '--port', " \
           f"'{http}', '--grpc-port', '{grpc}']))"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    return subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**env, "CI": "1"}, start_new_session=True)


def _listening(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex(("127.0.0.1", port)) == 0


@pytest.mark.slow
def test_two_real_web_viewers_serve_side_by_side(recorded, tmp_path):
    """Two viewers at once, each on its own pair of ports: both pages load and both recordings are served."""
    from scaletwin_envs.recording import log_episode_rrd

    path = log_episode_rrd(recorded(), tmp_path / "ep.rrd", scene=False)
    ports = [(_free_port(), _free_port()) for _ in range(2)]
    procs = [_start_viewer(path, http, grpc) for http, grpc in ports]
    try:
        deadline = time.monotonic() + 60
        pending = set(range(2))
        while pending and time.monotonic() < deadline:
            for k in list(pending):
                http, grpc = ports[k]
                assert procs[k].poll() is None, procs[k].communicate()[1][-2000:]
                if _listening(http) and _listening(grpc):
                    with urllib.request.urlopen(viewer_url(http, grpc), timeout=10) as page:
                        assert page.status == 200 and b"<html" in page.read(4096).lower()
                    pending.discard(k)
            time.sleep(0.5)
        assert not pending, "a viewer did not come up"
    finally:
        for p in procs:
            os.killpg(p.pid, signal.SIGTERM)  # the viewer and the rerun process it started
        for p in procs:
            out, _ = p.communicate(timeout=30)
    first = out.splitlines()[0]
    assert first.startswith("open http://127.0.0.1:") and str(ports[1][1]) in first


def test_stopping_the_command_stops_the_viewer_it_started(recorded, tmp_path):
    """SIGTERM to ``scaletwin view`` alone (as a service manager or a closed terminal sends it) stops rerun's
    viewer too: ``python -m rerun`` runs rerun's binary as a child of its own, which used to be left serving both
    ports. The address is printed only once the page is served."""
    from scaletwin_envs.recording import log_episode_rrd

    path = log_episode_rrd(recorded(), tmp_path / "ep.rrd", scene=False)
    http, grpc = _free_port(), _free_port()
    code = f"from scaletwin.cli import main; raise SystemExit(main(['view', {str(path)!r}, '--web', '--port', " \
           f"'{http}', '--grpc-port', '{grpc}']))"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env)
    try:
        first = proc.stdout.readline()  # blocks until the address is printed (or the command ends)
        assert first.startswith("open http://127.0.0.1:"), (first, proc.stderr.read() if proc.poll() else "")
        assert _listening(http), "the address was printed before the page was served"
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 130
    finally:
        if proc.poll() is None:
            proc.kill()
    deadline = time.monotonic() + 10
    while (_listening(http) or _listening(grpc)) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _listening(http) and not _listening(grpc), "the viewer outlived scaletwin view"
