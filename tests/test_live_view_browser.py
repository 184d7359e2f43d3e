"""`radseek view` in a real browser, opt-in (RADSEEK_BROWSER_TEST=1): Foxglove Studio's core (npm
@foxglove/studio-base 1.48.0, whose webpack build exports the App) mounted by a local page
(tests/support/foxglove_viewer), opened by Debian's Chromium headless through playwright-core, connected to the live
view of a whole `radseek run` with the subprotocol it speaks, foxglove.websocket.v1 (launch/ws_relay.py). The 3D
panel must draw the flight: the bounds, the track, the estimate. It needs chromium (`apt-get install chromium`; or
CHROMIUM=path) and node/npm; the npm packages go into runs/ (git-ignored) on first use, as the reference client's.
The screenshots stay in runs/test-live-view-browser/ (docs/img/live-view-foxglove-studio.png is one)."""

from __future__ import annotations

import functools
import json
import os
import shutil
import subprocess
import sys
import threading
import time
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import quote

import numpy as np
import pytest
from PIL import Image

from tests.conftest import REPO, free_port

pytestmark = [pytest.mark.slow, pytest.mark.io, pytest.mark.timeout(900)]
PAGE = REPO / "tests" / "support" / "foxglove_viewer"
NPM_DIR = REPO / "runs" / ".npm-foxglove-viewer"
PACKAGES = ["@foxglove/studio-base@1.48.0", "react@17.0.2", "react-dom@17.0.2", "playwright-core@1.65.2"]
KEEP = REPO / "runs" / "test-live-view-browser"
# radseek_cli/live_view.py's colours (0..1) as the canvas shows them (lines are unlit)
TRACK = (51, 128, 255)
BOUNDS = (153, 153, 153)


def _viewer_packages() -> Path:
    if not (NPM_DIR / "node_modules" / "playwright-core").is_dir():
        npm = shutil.which("npm")
        assert npm, "npm is needed to fetch the viewer (apt-get install npm)"
        NPM_DIR.mkdir(parents=True, exist_ok=True)
        subprocess.run([npm, "install", "--no-audit", "--no-fund", "--prefix", str(NPM_DIR), *PACKAGES], check=True,
                       capture_output=True, timeout=600)
    return NPM_DIR / "node_modules"


class _Quiet(SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:
        pass


def _serve(root: Path) -> tuple[ThreadingHTTPServer, int]:
    server = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_Quiet, directory=str(root)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, server.server_address[1]


def _near(rgb: np.ndarray, colour: tuple[int, int, int], tol: int) -> int:
    return int((np.abs(rgb.astype(int) - np.array(colour)).max(axis=-1) <= tol).sum())


def _stop(proc: subprocess.Popen | None) -> None:
    if proc is not None and proc.poll() is None:
        proc.terminate()
        try:  # a wait bound only
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_foxglove_studio_in_chromium_draws_the_live_flight(tmp_path):
    if os.environ.get("RADSEEK_BROWSER_TEST") != "1":
        pytest.skip("opt-in: RADSEEK_BROWSER_TEST=1 (Chromium, node, ~200 MB of npm packages)")
    chromium = os.environ.get("CHROMIUM", "/usr/bin/chromium")
    assert Path(chromium).exists(), f"no browser at {chromium}: apt-get install chromium, or set CHROMIUM"
    node = shutil.which("node")
    assert node, "node is needed to drive the browser (apt-get install nodejs)"
    modules = _viewer_packages()

    web = tmp_path / "web"
    web.mkdir()
    for name in ("index.html", "viewer.js", "layout.json"):
        shutil.copy(PAGE / name, web / name)
    (web / "node_modules").symlink_to(modules)
    server, http_port = _serve(web)

    out, shots, done = tmp_path / "run", tmp_path / "shots", tmp_path / "done"
    shots.mkdir()
    ws_port = free_port()
    run = view = browser = None
    try:
        # slow enough that the browser joins early in the flight; the view draws the track from its own start
        run = subprocess.Popen([sys.executable, "-m", "radseek_cli", "run", "--out", str(out), "--speedup", "4", "-q"],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        observer = out / "zenoh" / "observer.json5"
        deadline = time.monotonic() + 120  # bounds the wait only
        while not observer.exists() and run.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert observer.exists(), "radseek run wrote no observer credentials"
        view = subprocess.Popen([sys.executable, "-m", "radseek_cli", "view", "--zenoh-config", str(observer),
                                 "--port", str(ws_port), "--duration", "900"],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        assert "Foxglove WebSocket on" in view.stdout.readline()
        url = (f"http://127.0.0.1:{http_port}/index.html?layoutId=radseek&ds=foxglove-websocket"
               f"&ds.url={quote(f'ws://127.0.0.1:{ws_port}', safe='')}")
        browser = subprocess.Popen([node, str(PAGE / "shoot.js"), url, str(shots), str(done), "600"],
                                   stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                   env={**os.environ, "CHROMIUM": chromium, "NODE_PATH": str(modules)})
        run_out, _ = run.communicate(timeout=600)
        assert run.returncode == 0, run_out[-3000:]
        done.touch()
        browser_out, _ = browser.communicate(timeout=300)
        assert browser.returncode == 0, browser_out[-3000:]
    finally:
        for proc in (browser, run, view):
            _stop(proc)
        server.shutdown()
        server.server_close()
    KEEP.mkdir(parents=True, exist_ok=True)
    for png in shots.glob("*.png"):
        shutil.copy(png, KEEP / png.name)

    result = json.loads((shots / "result.json").read_text())
    assert not result["pageErrors"] and result["viewerError"] is None, result
    # the sidebar names the live view as the connected source and lists its scene channel (it wraps the URL)
    text = "".join(result["text"].split())
    assert f"ws://127.0.0.1:{ws_port}" in text, result["text"][:2000]
    assert "/mapfoxglove.SceneUpdate" in text, result["text"][:2000]
    assert not [e for e in result["consoleErrors"] if "/map" in e], result["consoleErrors"]
    # the 3D panel drew the flight: the bounds' loop, the vehicle's track, the red estimate
    canvas = np.asarray(Image.open(shots / "canvas.png").convert("RGB"))
    assert _near(canvas, BOUNDS, 12) > 1000, "no bounds drawn"
    assert _near(canvas, TRACK, 30) > 1000, "no track drawn"
    red = (canvas[..., 0] > 180) & (canvas[..., 1] < 80) & (canvas[..., 2] < 80)
    assert red.sum() > 20, "no estimate drawn"
