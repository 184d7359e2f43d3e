"""Interoperability: MAVProxy (headless, on the GCS port) connects to the vehicle process and lists the
mission that an API client uploaded, item by item."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as M

from vehicle_sim.harness import Gcs, VehicleProcess, free_udp_port, item

pytestmark = pytest.mark.slow
MAVPROXY = Path(sys.executable).parent / "mavproxy.py"


def test_mavproxy_lists_the_uploaded_mission():
    exe = str(MAVPROXY) if MAVPROXY.exists() else shutil.which("mavproxy.py")
    assert exe, "MAVProxy missing: `make` installs it with pip --no-deps (see Makefile)"
    api, gcs_port = free_udp_port(), free_udp_port()
    lat, lon = 47.397742, 8.545594
    items = [item(0, M.MAV_CMD_NAV_TAKEOFF, lat, lon, 3.0), item(1, M.MAV_CMD_NAV_WAYPOINT, lat + 1e-4, lon, 3.0, 42.0),
             item(2, M.MAV_CMD_NAV_LOITER_TIME, lat + 1e-4, lon + 1e-4, 4.0, 7.0), item(3, M.MAV_CMD_NAV_LAND)]
    with VehicleProcess(api, gcs_port, ["--speedup", "5"]), Gcs(api) as api_client:
        api_client.wait_vehicle()
        assert api_client.upload(items) == M.MAV_MISSION_ACCEPTED
        script = "sleep 2; echo 'wp list'; sleep 2; echo 'mode'; sleep 0.5"
        proc = subprocess.run(f"({script}) | {exe} --master=udpin:127.0.0.1:{gcs_port} --no-state",
                              shell=True, capture_output=True, text=True, timeout=60)
    out = proc.stdout + proc.stderr
    print(out)
    assert "Detected vehicle 1:1" in out
    assert "Requesting 4 waypoints" in out
    # MAVProxy prints each item as "command frame lat lon alt p1=... p2=... p3=... p4=... cur= auto="
    listed = [ln.split() for ln in out.splitlines() if " p1=" in ln]
    assert [(int(f[0]), int(f[1])) for f in listed] == [(22, 6), (16, 6), (19, 6), (21, 6)]
    assert float(listed[1][2]) == pytest.approx(lat + 1e-4, abs=1e-7) and listed[1][5] == "p1=42.0"
    assert float(listed[2][4]) == pytest.approx(4.0) and listed[2][5] == "p1=7.0"
    assert "LOITER" in out and "MISSION" in out  # PX4 mode names from our custom modes
    assert "fence breach" not in out
