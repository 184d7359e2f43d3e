"""`radseek mission` with no router: --connect-timeout governs the wait, and the answer is one line."""

import subprocess
import sys

import pytest

from tests.conftest import REPO, free_port

pytestmark = pytest.mark.io


def test_no_router_is_one_line_after_the_connect_timeout(tmp_path):
    scenario = REPO.parent / "shared" / "datasets" / "lattice-clean" / "scenario.json"
    r = subprocess.run([sys.executable, "-m", "radseek_cli", "mission", "--scenario", str(scenario),
                        "--out", str(tmp_path / "m"), "--connect", f"tcp/127.0.0.1:{free_port()}",
                        "--connect-timeout", "2"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 1
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "no zenoh router" in lines[0] and "after 2 s" in lines[0], r.stderr
    assert "Traceback" not in r.stderr and ".rs:" not in lines[0]
