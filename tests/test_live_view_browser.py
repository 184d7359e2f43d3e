"""`radseek view` and flight.mcap in a real browser, opt-in (RADSEEK_BROWSER_TEST=1): Foxglove Studio's core (npm
@foxglove/studio-base 1.48.0, whose webpack build exports the App) mounted by a local page
(tests/support/foxglove_viewer), opened by Debian's Chromium headless through playwright-core, connected to the live
view of a whole `radseek run` with the subprotocol it speaks, foxglove.websocket.v1 (launch/ws_relay.py). The 3D
panel must draw the flight: the bounds, the track, the estimate; and Studio must list no problem: no channel refused
(its JSON-schema reader takes few forms: tests/support/studio_reader.py). Then the same Studio opens that run's
flight.mcap from a server that answers HTTP range requests, as Studio's remote-file source needs, and again lists
no problem; its Raw Messages panel shows a raw board frame's fields (the ros1 channel). It needs chromium
(`apt-get install chromium`; or CHROMIUM=path) and node/npm; the npm packages go into runs/ (git-ignored) on first
use, as the reference client's. The screenshots stay in runs/test-live-view-browser/ (docs/img/live-view-foxglove-
studio.png is one)."""

from __future__ import annotations

import functools
import json
import os
import re
import shutil
import subprocess
import sys
import threading
import time
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from types import SimpleNamespace
from urllib.parse import quote

import numpy as np
import pytest
from PIL import Image

from radseek import topics
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
    """The page's files, and byte ranges of them (``Range: bytes=A-B``, answered 206 with ``Content-Range``; every
    answer says ``Accept-Ranges: bytes``), which Studio's remote-file source needs to read an MCAP file by its index;
    ``python3 -m http.server`` answers no range."""

    def log_message(self, *args) -> None:
        pass

    def end_headers(self) -> None:
        self.send_header("Accept-Ranges", "bytes")
        super().end_headers()

    def send_head(self):
        m = re.fullmatch(r"bytes=(\d*)-(\d*)", self.headers.get("Range", ""))
        path = Path(self.translate_path(self.path))
        if not m or not path.is_file():
            return super().send_head()
        size = path.stat().st_size
        start, end = (int(m[1]), int(m[2] or size - 1)) if m[1] else (max(size - int(m[2]), 0), size - 1)
        end = min(end, size - 1)
        if start > end:
            self.send_error(416)
            return None
        f = open(path, "rb")  # noqa: SIM115 - closed by copyfile's caller
        f.seek(start)
        self.send_response(206)
        self.send_header("Content-Type", self.guess_type(str(path)))
        self.send_header("Content-Range", f"bytes {start}-{end}/{size}")
        self.send_header("Content-Length", str(end - start + 1))
        self.end_headers()
        self._left = end - start + 1
        return f

    def copyfile(self, source, outputfile) -> None:
        left = getattr(self, "_left", None)
        try:
            if left is None:
                super().copyfile(source, outputfile)
                return
            while left > 0:
                chunk = source.read(min(left, 1 << 16))
                if not chunk:
                    return
                outputfile.write(chunk)
                left -= len(chunk)
        except (BrokenPipeError, ConnectionResetError):  # Studio aborts its first, whole-file GET at once
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


def _browser() -> tuple[str, str, Path]:
    if os.environ.get("RADSEEK_BROWSER_TEST") != "1":
        pytest.skip("opt-in: RADSEEK_BROWSER_TEST=1 (Chromium, node, ~200 MB of npm packages)")
    chromium = os.environ.get("CHROMIUM", "/usr/bin/chromium")
    assert Path(chromium).exists(), f"no browser at {chromium}: apt-get install chromium, or set CHROMIUM"
    node = shutil.which("node")
    assert node, "node is needed to drive the browser (apt-get install nodejs)"
    return chromium, node, _viewer_packages()


def _web(root: Path, modules: Path) -> Path:
    root.mkdir()
    for name in ("index.html", "viewer.js", "layout.json", "layout-mcap.json"):
        shutil.copy(PAGE / name, root / name)
    (root / "node_modules").symlink_to(modules)
    return root


def _shoot(node: str, chromium: str, modules: Path, url: str, shots: Path, done: Path, *wait_text: str):
    shots.mkdir()
    return subprocess.Popen([node, str(PAGE / "shoot.js"), url, str(shots), str(done), "600", *wait_text],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "CHROMIUM": chromium, "NODE_PATH": str(modules)})


def _keep(shots: Path, prefix: str = "") -> dict:
    KEEP.mkdir(parents=True, exist_ok=True)
    for png in shots.glob("*.png"):
        shutil.copy(png, KEEP / f"{prefix}{png.name}")
    return json.loads((shots / "result.json").read_text())


def _no_problem(result: dict) -> None:
    """Studio listed no problem for the data source: no channel refused, no message it could not read."""
    assert not result["pageErrors"] and result["viewerError"] is None, result
    assert not [e for e in result["consoleErrors"] if "Player problem" in e], result["consoleErrors"]
    problems = [f"{p['message']}: {p['details']}" for p in result["problems"]]
    assert not problems, "Studio's problems:\n" + "\n".join(problems)
    assert result["problemsTab"].strip() == "Problems" and result["noProblemsShown"], result["problemsTab"]


@pytest.fixture(scope="module")
def live_flight(tmp_path_factory):
    """One `radseek run` (default scene, 4x) watched live in Studio through `radseek view`; its OUT folder and what
    the page reported."""
    chromium, node, modules = _browser()
    tmp = tmp_path_factory.mktemp("live-view-browser")
    server, http_port = _serve(_web(tmp / "web", modules))
    out, shots, done = tmp / "run", tmp / "shots", tmp / "done"
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
        browser = _shoot(node, chromium, modules, url, shots, done)
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
    return SimpleNamespace(out=out, shots=shots, ws_port=ws_port, result=_keep(shots))


def test_foxglove_studio_in_chromium_draws_the_live_flight(live_flight):
    result, shots = live_flight.result, live_flight.shots
    _no_problem(result)  # every channel the view advertises is read: none refused for its schema
    # the sidebar names the live view as the connected source and lists its scene channel (it wraps the URL)
    text = "".join(result["text"].split())
    assert f"ws://127.0.0.1:{live_flight.ws_port}" in text, result["text"][:2000]
    assert "/mapfoxglove.SceneUpdate" in text, result["text"][:2000]
    for name in ("Histogram", "DetectorStatus", "Plan", "Estimate"):  # the four channels Studio refused before
        assert f"radseek.{name}" in text, result["text"][:3000]
    assert not [e for e in result["consoleErrors"] if "/map" in e], result["consoleErrors"]
    # the 3D panel drew the flight: the bounds' loop, the vehicle's track, the red estimate
    canvas = np.asarray(Image.open(shots / "canvas.png").convert("RGB"))
    assert _near(canvas, BOUNDS, 12) > 1000, "no bounds drawn"
    assert _near(canvas, TRACK, 30) > 1000, "no track drawn"
    red = (canvas[..., 0] > 180) & (canvas[..., 1] < 80) & (canvas[..., 2] < 80)
    assert red.sum() > 20, "no estimate drawn"


def test_foxglove_studio_opens_the_runs_flight_mcap_with_no_channel_refused(live_flight, tmp_path):
    """The run's flight.mcap from a range-answering server (Studio's remote-file source), seeked into the flight:
    Studio lists no problem for its channels (mavlink/*, radseek/*, the raw frames and the Foxglove ones), and its
    Raw Messages panel shows a raw board frame decoded from the ros1 channel."""
    from mcap.reader import make_reader

    chromium, node, modules = _browser()
    web = _web(tmp_path / "web", modules)
    (web / "flight.mcap").symlink_to(live_flight.out / "flight.mcap")
    with open(web / "flight.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    channels = {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
    assert topics.key(topics.RAW_FRAME) in channels and sum(c.startswith("mavlink/") for c in channels) >= 10
    server, http_port = _serve(web)
    done = tmp_path / "done"
    done.touch()  # nothing to wait for but the file's first messages (WAIT_TEXT)
    browser = None
    try:
        url = (f"http://127.0.0.1:{http_port}/index.html?layoutId=radseek&layoutFile=layout-mcap.json"
               f"&ds=remote-file&ds.url={quote(f'http://127.0.0.1:{http_port}/flight.mcap', safe='')}"
               "&time=1970-01-01T00:00:40Z")  # 40 s of sim time (log time is sim time from 0)
        browser = _shoot(node, chromium, modules, url, tmp_path / "shots", done, "integration_us")
        browser_out, _ = browser.communicate(timeout=700)
        assert browser.returncode == 0, browser_out[-3000:]
    finally:
        _stop(browser)
        server.shutdown()
        server.server_close()
    result = _keep(tmp_path / "shots", "mcap-")
    _no_problem(result)
    # the sidebar's topic list has every channel of the file with its schema (a refused one is left out)
    text = " ".join(result["text"].split())
    listed = [f"{topic} {schema}" for topic, schema in sorted(channels.items()) if f"{topic} {schema} " not in text]
    assert not listed, f"not listed by Studio: {listed}"
    # the raw frame at 40 s, its fields as the board sent them: 100 ms integrated, version 1, 90 bytes
    for field, value in (("integration_us", "100000"), ("version", "1"), ("length", "90")):
        assert re.search(rf"{field} {value}\b", text), text[:3000]
