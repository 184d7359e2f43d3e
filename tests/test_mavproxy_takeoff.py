"""Interoperability: MAVProxy's `takeoff 5` (MAV_CMD_NAV_TAKEOFF with 5 in param7, which PX4 reads as AMSL) is
accepted as PX4 accepts it: an altitude below home + MIS_TAKEOFF_ALT is raised to that minimum, announced with
PX4's "Using minimum takeoff altitude" (navigator/takeoff.cpp). MAVProxy is driven by what it prints."""

import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from vehicle_sim.harness import Gcs, VehicleProcess, free_udp_port

pytestmark = [pytest.mark.slow, pytest.mark.io]
MAVPROXY = Path(sys.executable).parent / "mavproxy.py"
WAIT_S = 60.0  # bounds waiting only


def test_mavproxy_takeoff_5_climbs_to_the_minimum_takeoff_altitude():
    exe = str(MAVPROXY) if MAVPROXY.exists() else shutil.which("mavproxy.py")
    assert exe, "MAVProxy missing: `make` installs it with pip --no-deps (see Makefile)"
    api, gcs_port = free_udp_port(), free_udp_port()
    with VehicleProcess(api, gcs_port, ["--speedup", "5"]), Gcs(api) as api_client:
        api_client.wait_vehicle()
        mavproxy = subprocess.Popen([exe, f"--master=udpin:127.0.0.1:{gcs_port}", "--no-state"],
                                    stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                    text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        lines: list[str] = []
        reader = threading.Thread(target=lambda: lines.extend(mavproxy.stdout), daemon=True)
        reader.start()

        def wait_for(text: str) -> None:
            deadline = time.monotonic() + WAIT_S
            while text not in "".join(lines):
                assert mavproxy.poll() is None, f"MAVProxy exited waiting for {text!r}:\n{''.join(lines)}"
                assert time.monotonic() < deadline, f"MAVProxy: no {text!r} in {WAIT_S} s:\n{''.join(lines)}"
                time.sleep(0.05)

        def send(cmd: str) -> None:
            mavproxy.stdin.write(cmd + "\n")
            mavproxy.stdin.flush()

        try:
            wait_for("Detected vehicle 1:1")
            send("arm throttle")
            wait_for("ARMED")
            send("takeoff 5")
            wait_for("Using minimum takeoff altitude: 2.50 m")
            pos = api_client.recv("LOCAL_POSITION_NED", lambda m: m.z < -2.4, timeout=WAIT_S)
            later = [api_client.recv("LOCAL_POSITION_NED", timeout=WAIT_S) for _ in range(30)]
        finally:
            mavproxy.stdin.close()
            try:
                mavproxy.wait(30)
            except subprocess.TimeoutExpired:
                mavproxy.kill()
                mavproxy.wait()
            reader.join(5)
    out = "".join(lines)
    assert "NAV_TAKEOFF: ACCEPTED" in out
    assert pos.z < -2.4
    assert all(-2.6 < m.z < -2.4 for m in later[-10:])  # holds at MIS_TAKEOFF_ALT (2.5 m), not 5 m
