"""`radseek mission` with no router: --connect-timeout governs the wait, and the answer is one line."""

import subprocess
import sys

import pytest

from benchmarks.shared_data import shared_path
from tests.conftest import free_port

pytestmark = pytest.mark.io


def test_no_router_is_one_line_after_the_connect_timeout(tmp_path):
    scenario = shared_path("datasets", "lattice-clean", "scenario.json")
    r = subprocess.run([sys.executable, "-m", "radseek_cli", "mission", "--scenario", str(scenario),
                        "--out", str(tmp_path / "m"), "--connect", f"tcp/127.0.0.1:{free_port()}",
                        "--connect-timeout", "2"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 1
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "no zenoh router" in lines[0] and "after 2 s" in lines[0], r.stderr
    assert "Traceback" not in r.stderr and ".rs:" not in lines[0]


def test_no_detector_is_one_line_after_the_connect_timeout(router, tmp_path):
    """A router and an autopilot but no detector: the first histogram's wait is --connect-timeout's too."""
    from vehicle_sim.harness import free_udp_port

    api = free_udp_port()
    vehicle = subprocess.Popen([sys.executable, "-m", "radseek_cli", "vehicle", "--connect", router, "--speedup", "5",
                                "--api-port", str(api), "--gcs-port", str(free_udp_port()),
                                "--api-local-port", "0", "--gcs-local-port", "0"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        scenario = shared_path("datasets", "lattice-clean", "scenario.json")
        r = subprocess.run([sys.executable, "-m", "radseek_cli", "mission", "--scenario", str(scenario),
                            "--out", str(tmp_path / "m"), "--connect", router, "--url", f"udpin://0.0.0.0:{api}",
                            "--connect-timeout", "3"], capture_output=True, text=True, timeout=300)
    finally:
        vehicle.terminate()
        vehicle.wait(60)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 1, r.stderr[-3000:]
    assert lines[-1].startswith("radseek mission: no detector histograms after 3 s"), r.stderr[-3000:]
    assert "heard: " in lines[-1] and "pose " in lines[-1], lines[-1]  # what it did hear: the vehicle's poses
    assert "Traceback" not in r.stderr
    assert (tmp_path / "m" / "frames.csv").is_file()  # what was recorded (nothing yet) stays a dataset's frames
