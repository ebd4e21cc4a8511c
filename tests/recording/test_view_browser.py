"""``scaletwin view`` in a real browser: the address it prints opens the recording in rerun's web viewer.

A dig episode is recorded with ``scaletwin simulate --rrd``, served with ``scaletwin view --web`` on free ports, and
the printed address is opened in headless Chromium (software WebGL, every request that leaves 127.0.0.1 refused:
the viewer must work on a machine with no network). The viewer draws on a canvas, so the page's text is not in
the DOM; what it shows is read from the viewer's own state (``window._handle.viewer_state()``, rerun's web
handle: the open recording, its timelines and the views of the layout stored in the file, with their entity
roots). A screenshot of the page is kept next to the recording for a person to look at.

Needs Chromium (``apt-get install chromium``, or ``SCALETWIN_CHROMIUM=/path/to/chrome``) and Playwright for Python
(``pip install -e ".[browser]"``); slow (about 30 s: the viewer's WebAssembly compiles in a software renderer), so
deselected by default: ``pytest -m slow tests/recording/test_view_browser.py``.
"""

from __future__ import annotations

import os
import re
import selectors
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from scaletwin.cli.view import port_free

pytestmark = pytest.mark.slow


#: How long the viewer may take to compile its WebAssembly and load the recording in a software renderer (s).
LOAD_S = 90
#: Flags of a headless Chromium that renders WebGL in software and makes no background connections.
CHROMIUM_ARGS = ("--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync")
#: Views of the layout stored in every dig recording (scaletwin_envs.recording.rerun_log), as the viewer names
#: them: the loader in 3D, the dig-phase timeline, the pin forces and their two-route residual, one unit per axis.
VIEWS = ("Loader", "Dig phase", "Phase changes", "Pin forces", "Pin forces: route 2 − route 1 [N]",
         "Cylinder forces", "Cylinder forces: route 2 − route 1 [N]", "Cylinders [Pa]", "Cylinders [m]",
         "Cylinders [m/s]", "Bucket and load [m]", "Bucket and load [kg]", "Soil force")
ENTITY_ROOTS = ("/world", "/signals", "/phase", "/phases")
#: The recording's timelines: control steps and simulated time.
TIMELINES = (b"\x04step", b"\x08sim_time")


def _address(proc: subprocess.Popen[str], timeout: float) -> str:
    """The address ``scaletwin view`` prints (``open http://…``), read from its output within ``timeout`` s."""
    assert proc.stdout is not None
    seen: list[str] = []
    deadline = time.monotonic() + timeout
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        while time.monotonic() < deadline:
            if not sel.select(timeout=max(0.0, deadline - time.monotonic())):
                break
            line = proc.stdout.readline()
            if not line:
                break
            seen.append(line)
            if m := re.search(r"open (http://127\.0\.0\.1:\d+/\S*)", line):
                return m.group(1)
    raise AssertionError(f"scaletwin view printed no address within {timeout} s: {''.join(seen)!r}")


def test_the_printed_address_opens_the_recording_in_a_browser(tmp_path: Path) -> None:
    # checked here, not at import, so that the default run (slow tests deselected) does not report a skip
    playwright_api = pytest.importorskip("playwright.sync_api",
                                         reason='Playwright is not installed (pip install -e ".[browser]")')
    chromium = os.environ.get("SCALETWIN_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
    if not chromium:
        pytest.skip("no Chromium (apt-get install chromium, or set SCALETWIN_CHROMIUM)")
    rrd, shot = tmp_path / "dig.rrd", tmp_path / "viewer.png"
    cli = [sys.executable, "-c", "import sys; from scaletwin.cli import main; sys.exit(main())"]
    subprocess.run([*cli, "simulate", "--scale", "mini", "--rrd", str(rrd)], check=True, capture_output=True,
                   timeout=120)
    viewer = subprocess.Popen([*cli, "view", str(rrd), "--web", "--port", "0", "--grpc-port", "0"],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    refused: list[str] = []
    try:
        url = _address(viewer, 60.0)
        with playwright_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium, headless=True, args=list(CHROMIUM_ARGS))
            page = browser.new_page(viewport={"width": 1400, "height": 900})

            def refuse(route: object) -> None:
                refused.append(route.request.url)  # type: ignore[attr-defined]
                route.abort()  # type: ignore[attr-defined]

            page.route(lambda u: not u.startswith("http://127.0.0.1"), refuse)
            page.goto(url)
            state = b""
            deadline = time.monotonic() + LOAD_S
            while time.monotonic() < deadline:
                state = bytes(page.evaluate("window._handle ? Array.from(window._handle.viewer_state()) : []"))
                if all(x in state for x in (b"app_id=scaletwin", *TIMELINES, *(v.encode() for v in VIEWS))):
                    break
                time.sleep(1.0)
            page.screenshot(path=str(shot))
            browser.close()
    finally:
        viewer.terminate()  # SIGTERM, as a service manager or a closed terminal sends it
        viewer.wait(timeout=30)
    http_port = int(re.search(r"127\.0\.0\.1:(\d+)/", url).group(1))
    grpc_port = int(re.search(r"127\.0\.0\.1%3A(\d+)%2Fproxy", url).group(1))
    for port in (http_port, grpc_port):  # the viewer (rerun's binary, a grandchild) stopped with the command
        assert port_free(port), f"port {port} still served after scaletwin view was stopped"
    text = state.decode("utf-8", errors="replace")
    assert "app_id=scaletwin" in text, f"the viewer opened no scaletwin recording within {LOAD_S} s: {text[:300]!r}"
    missing = [v for v in VIEWS if v not in text]
    assert not missing, f"views of the stored layout not shown: {missing}"
    assert all(root in text for root in ENTITY_ROOTS), text
    assert all(t.decode() in text for t in TIMELINES), "the recording's timelines are missing"
    assert shot.stat().st_size > 50_000, "the screenshot is (nearly) blank"
    assert all(not u.startswith("http://127.0.0.1") for u in refused)
