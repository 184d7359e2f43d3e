"""Foxglove's own reference client (npm @foxglove/ws-protocol-examples, `simple-client`, which offers the subprotocol
foxglove.websocket.v1) connects to `radseek view` and decodes its /map SceneUpdate and the relayed JSON topics.
The package is installed from the npm registry into runs/ (git-ignored) on first use, as the MAVSDK examples' venv
is. Real processes: a zenoh router, `radseek view`, node."""

from __future__ import annotations

import shutil
import subprocess
import sys
import time

import pytest

from radseek import topics
from radseek.zenoh_session import open_session
from tests.conftest import REPO, free_port

pytestmark = [pytest.mark.slow, pytest.mark.io, pytest.mark.timeout(600)]
NPM_DIR = REPO / "runs" / ".npm-foxglove"
CLIENT = NPM_DIR / "node_modules" / ".bin" / "ws-protocol-examples"


def _client() -> str:
    if not CLIENT.exists():
        npm = shutil.which("npm")
        assert npm, "npm is needed to fetch Foxglove's reference client (apt install npm)"
        NPM_DIR.mkdir(parents=True, exist_ok=True)
        subprocess.run([npm, "install", "--no-audit", "--no-fund", "--prefix", str(NPM_DIR),
                        "@foxglove/ws-protocol-examples@0"], check=True, capture_output=True, timeout=300)
    return str(CLIENT)


def test_the_reference_client_decodes_the_map_and_a_topic(router):
    client = _client()
    port = free_port()
    view = subprocess.Popen([sys.executable, "-m", "radseek_cli", "view", "--connect", router, "--port", str(port),
                             "--duration", "120"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    node = None
    try:
        assert "Foxglove WebSocket on" in view.stdout.readline()
        node = subprocess.Popen([client, "simple-client", f"ws://127.0.0.1:{port}"], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
        lines: list[str] = []
        with open_session(None, router) as session:
            deadline = time.monotonic() + 60
            k = 0
            while time.monotonic() < deadline:
                k += 1
                session.put(topics.key(topics.POSE), topics.Pose(t=0.1 * k, x=1, y=2, z=1.5, yaw=0, var_x=0.01,
                                                                  var_y=0.01, var_z=0.01, var_yaw=0.01).to_bytes())
                time.sleep(0.1)
                if k == 50:
                    break
        node.terminate()
        out, _ = node.communicate(timeout=30)
        lines = out.splitlines()
    finally:
        if node is not None and node.poll() is None:
            node.kill()
        view.terminate()
        view.wait(30)
    text = "\n".join(lines)
    assert "Error" not in text, text[-2000:]
    assert "SceneUpdate" in text and "var_yaw: 0.01" in text, text[-2000:]
