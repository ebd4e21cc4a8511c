"""``scaletwin view``: open an ``.rrd`` recording in the rerun viewer, or serve the web viewer on 127.0.0.1.

The web viewer takes two ports: HTTP (``--port``, the page) and gRPC (``--grpc-port``, the recording, which the page
fetches from rerun's message proxy). The address printed opens the recording directly
(``http://127.0.0.1:HTTP/?url=rerun+http://127.0.0.1:GRPC/proxy``, URL-encoded); the bare HTTP address shows
rerun's welcome page only. A port left at its default moves to a free one when taken (a second viewer then just
works); one given explicitly must be free; 0 picks a free one. The address is printed once the page is served, so
it opens at once. On a remote machine both ports must be forwarded,
e.g. ``ssh -L 9090:127.0.0.1:9090 -L 9876:127.0.0.1:9876 user@host``, which the command prints.
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from urllib.parse import quote

from scaletwin.cli import CommandError

DEFAULT_HTTP_PORT = 9090  # rerun's default web viewer port
DEFAULT_GRPC_PORT = 9876  # rerun's default gRPC (message proxy) port
HOST = "127.0.0.1"
READY_S = 60.0  # how long the web viewer may take to serve its page before the command gives up (s)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("view", help="open a .rrd file in the rerun viewer (web viewer on 127.0.0.1 without a display)")
    p.add_argument("file", help="a .rrd file (e.g. from scaletwin simulate --rrd)")
    p.add_argument("--web", action="store_true", help="serve the web viewer even when a display is available")
    p.add_argument("--port", type=int, default=None,
                   help=f"web viewer HTTP port (default {DEFAULT_HTTP_PORT}, or a free one if taken; 0: a free one)")
    p.add_argument("--grpc-port", type=int, default=None,
                   help=f"gRPC port the viewer fetches the recording from (default {DEFAULT_GRPC_PORT}, or a free one "
                        "if taken; 0: a free one)")
    p.add_argument("--dry-run", action="store_true", help="print the rerun command and the address instead of running")
    p.set_defaults(func=run)


def has_display() -> bool:
    """Whether a native viewer window can open (always on macOS/Windows; X11 or Wayland on Linux)."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def port_free(port: int, host: str = HOST) -> bool:
    """Whether a TCP port can be bound on ``host`` now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def free_port(host: str = HOST, avoid: tuple[int, ...] = ()) -> int:
    """A port the OS reports free on ``host`` (it may be taken again before rerun binds it: a short race)."""
    for _ in range(20):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.bind((host, 0))
            port = int(s.getsockname()[1])
        if port not in avoid:
            return port
    raise CommandError("no free TCP port found on 127.0.0.1")


def choose_port(requested: int | None, default: int, option: str, avoid: tuple[int, ...] = ()) -> int:
    """The port to use: ``requested`` (must be free), 0 (a free one), or None (``default``, or a free one if taken)."""
    if requested is None:
        return default if default not in avoid and port_free(default) else free_port(avoid=avoid)
    if not 0 <= requested < 65536:
        raise CommandError(f"{option} must be in 1..65535 (0: pick a free port), got {requested}")
    if requested == 0:
        return free_port(avoid=avoid)
    if requested in avoid:
        raise CommandError(f"{option} {requested} is the other port too: the HTTP and gRPC ports must differ")
    if not port_free(requested):
        raise CommandError(f"{option} {requested} is in use on {HOST} (another viewer?): choose another, or leave "
                           f"{option} out to get a free one")
    return requested


def viewer_url(http_port: int, grpc_port: int, host: str = HOST) -> str:
    """The web viewer address that opens the recording: the page plus ``?url=`` of rerun's gRPC message proxy."""
    proxy = f"rerun+http://{host}:{grpc_port}/proxy"
    return f"http://{host}:{http_port}/?url={quote(proxy, safe='')}"


def viewer_command(path: Path, web: bool, port: int, grpc_port: int | None = None) -> list[str]:
    """The rerun CLI call (the rerun of this Python environment); the web viewer binds to loopback only."""
    cmd = [sys.executable, "-m", "rerun", str(path)]
    if web:
        cmd += ["--web-viewer", "--bind", HOST, "--web-viewer-port", str(port)]
    if grpc_port is not None:
        cmd += ["--port", str(grpc_port)]
    return cmd


def web_instructions(http_port: int, grpc_port: int) -> str:
    """What a user needs: the address, and the two ports to forward from a remote machine."""
    return (f"open {viewer_url(http_port, grpc_port)}\n"
            f"  (web viewer: HTTP port {http_port}, recording over gRPC port {grpc_port}, both on {HOST} only)\n"
            f"  on a remote machine, forward both ports first: "
            f"ssh -L {http_port}:{HOST}:{http_port} -L {grpc_port}:{HOST}:{grpc_port} USER@HOST")


def run(args: argparse.Namespace) -> int:
    path = Path(args.file)
    if not path.is_file():
        raise FileNotFoundError(f"no such recording: {path}")
    if path.suffix != ".rrd":
        raise CommandError(f"{path} is not a .rrd file (write one with: scaletwin simulate --rrd FILE)")
    web = args.web or not has_display()
    if not web:
        grpc = None if args.grpc_port is None else choose_port(args.grpc_port, DEFAULT_GRPC_PORT, "--grpc-port")
        cmd = viewer_command(path, False, DEFAULT_HTTP_PORT, grpc)
        if args.dry_run:
            print(" ".join(cmd))
            return 0
        return run_viewer(cmd)
    http = choose_port(args.port, DEFAULT_HTTP_PORT, "--port")
    grpc = choose_port(args.grpc_port, DEFAULT_GRPC_PORT, "--grpc-port", avoid=(http,))
    cmd = viewer_command(path, True, http, grpc)
    if args.dry_run:
        print(" ".join(cmd))
        print(web_instructions(http, grpc))
        return 0
    return run_viewer(cmd, lambda proc: wait_listening(http, proc, READY_S),
                      web_instructions(http, grpc) + "\n  (Ctrl-C to stop)")


def run_viewer(cmd: list[str], ready: Callable[[subprocess.Popen], bool] | None = None, banner: str = "") -> int:
    """Run the viewer ``cmd`` until it exits or this command is stopped (Ctrl-C or SIGTERM), printing ``banner``
    once ``ready(proc)`` says it serves (a False ends the run); its exit code, 130 when stopped.

    ``python -m rerun`` starts rerun's binary as a child of its own: the viewer runs in a process group of its own,
    and the whole group is stopped on the way out, so that no viewer is left serving its ports behind us."""
    proc = subprocess.Popen(cmd, start_new_session=True)

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        if ready is not None and not ready(proc):
            return proc.poll() or 1  # rerun ended (it said why), or never opened its port (stopped below)
        if banner:
            print(banner, flush=True)
        return proc.wait()
    except KeyboardInterrupt:
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
        stop_group(proc)


def stop_group(proc: subprocess.Popen, grace: float = 5.0) -> None:
    """SIGTERM to ``proc``'s process group (it leads one), SIGKILL after ``grace`` s if anything of it is left."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=grace)
        except subprocess.TimeoutExpired:
            continue
        deadline = time.monotonic() + grace
        while time.monotonic() < deadline:  # the leader is gone; wait for the rest of its group
            try:
                os.killpg(proc.pid, 0)
            except ProcessLookupError:
                return
            time.sleep(0.05)


def wait_listening(port: int, proc: subprocess.Popen, timeout: float, host: str = HOST) -> bool:
    """Wait until ``host:port`` accepts connections (the viewer's page is served), so that the address printed
    opens at once; False if ``proc`` ended first or ``timeout`` (s) passed."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            return False
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.settimeout(0.5)
            if s.connect_ex((host, port)) == 0:
                return True
        time.sleep(0.1)
    print(f"scaletwin view: the web viewer did not open port {port} within {timeout:.0f} s; stopping it",
          file=sys.stderr)
    return False
