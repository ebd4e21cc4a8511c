"""``scaletwin view``: open an ``.rrd`` recording in the rerun viewer, or serve the web viewer on 127.0.0.1."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

from scaletwin.cli import CommandError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("view", help="open a .rrd file in the rerun viewer (web viewer on 127.0.0.1 without a display)")
    p.add_argument("file", help="a .rrd file (e.g. from scaletwin simulate --rrd)")
    p.add_argument("--web", action="store_true", help="serve the web viewer even when a display is available")
    p.add_argument("--port", type=int, default=9090, help="web viewer HTTP port (default 9090)")
    p.add_argument("--dry-run", action="store_true", help="print the rerun command instead of running it")
    p.set_defaults(func=run)


def has_display() -> bool:
    """Whether a native viewer window can open (always on macOS/Windows; X11 or Wayland on Linux)."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def viewer_command(path: Path, web: bool, port: int) -> list[str]:
    """The rerun CLI call (the rerun of this Python environment); the web viewer binds to loopback only."""
    cmd = [sys.executable, "-m", "rerun", str(path)]
    if web:
        cmd += ["--web-viewer", "--bind", "127.0.0.1", "--web-viewer-port", str(port)]
    return cmd


def run(args: argparse.Namespace) -> int:
    path = Path(args.file)
    if not path.is_file():
        raise FileNotFoundError(f"no such recording: {path}")
    if path.suffix != ".rrd":
        raise CommandError(f"{path} is not a .rrd file (write one with: scaletwin simulate --rrd FILE)")
    if not 0 < args.port < 65536:
        raise CommandError(f"--port must be in 1..65535, got {args.port}")
    web = args.web or not has_display()
    cmd = viewer_command(path, web, args.port)
    if args.dry_run:
        print(" ".join(cmd))
        return 0
    if web:
        print(f"serving the rerun web viewer on http://127.0.0.1:{args.port} (Ctrl-C to stop)", file=sys.stderr)
    return subprocess.call(cmd)
