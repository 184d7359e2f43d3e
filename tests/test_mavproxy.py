"""Interoperability: MAVProxy (headless, on the GCS port) connects to the vehicle process and lists the
mission that an API client uploaded, item by item; downloads the flight log (log and ftp modules); runs shell
commands through its nsh module.

MAVProxy is driven by what it prints (each command is sent once the output it depends on has appeared),
not by fixed sleeps, so a slow start on a loaded host only makes the test wait longer."""


import contextlib
import io

import pytest
from pymavlink.dialects.v20 import common as M
from pyulog import ULog

from tests.support.mavproxy import MavProxy
from vehicle_sim.harness import Gcs, VehicleProcess, free_udp_port, item

pytestmark = pytest.mark.slow


def test_mavproxy_lists_the_uploaded_mission():
    api, gcs_port = free_udp_port(), free_udp_port()
    lat, lon = 47.397742, 8.545594
    items = [item(0, M.MAV_CMD_NAV_TAKEOFF, lat, lon, 3.0), item(1, M.MAV_CMD_NAV_WAYPOINT, lat + 1e-4, lon, 3.0, 42.0),
             item(2, M.MAV_CMD_NAV_LOITER_TIME, lat + 1e-4, lon + 1e-4, 4.0, 7.0), item(3, M.MAV_CMD_NAV_LAND)]
    with VehicleProcess(api, gcs_port, ["--speedup", "5"]), Gcs(api) as api_client:
        api_client.wait_vehicle()
        assert api_client.upload(items) == M.MAV_MISSION_ACCEPTED
        with MavProxy(gcs_port) as mp:
            mp.wait_for("Detected vehicle 1:1", "vehicle detected")
            mp.send("wp list")
            mp.wait_for(lambda out: sum(" p1=" in ln for ln in out.splitlines()) >= 4, "4 listed waypoints")
            mp.send("mode")
            mp.wait_for("Available modes:", "mode list")
    out = mp.output
    print(out)
    assert "Detected vehicle 1:1" in out
    assert "Requesting 4 waypoints" in out
    # MAVProxy prints each item as "command frame lat lon alt p1=... p2=... p3=... p4=... cur= auto="
    listed = [ln.split() for ln in out.splitlines() if " p1=" in ln]
    assert [(int(f[0]), int(f[1])) for f in listed] == [(22, 6), (16, 6), (19, 6), (21, 6)]
    assert float(listed[1][2]) == pytest.approx(lat + 1e-4, abs=1e-7) and listed[1][5] == "p1=42.0"
    assert float(listed[2][4]) == pytest.approx(4.0) and listed[2][5] == "p1=7.0"
    modes = out.split("Available modes:", 1)[1].splitlines()[0]
    assert "LOITER" in modes and "MISSION" in modes  # PX4 mode names from our custom modes
    assert "fence breach" not in out


def test_mavproxy_lists_and_downloads_the_flight_log_by_log_protocol_and_ftp(tmp_path):
    # MAVProxy's `log` (LOG_REQUEST_LIST / LOG_REQUEST_DATA) and `ftp` modules (loaded by default); its
    # `ftp get @PARAM/param.pck` (what it tries on ArduPilot) fails at once on the NAK instead of timing out
    api, gcs_port = free_udp_port(), free_udp_port()
    with VehicleProcess(api, gcs_port, []):
        with MavProxy(gcs_port, cwd=tmp_path) as mp:

            def run(command: str, cond, what: str) -> None:
                mp.send(command)
                mp.wait_for(cond, what)

            run("", lambda out: "Detected vehicle 1:1" in out and "parameters" in out, "vehicle and parameters")
            run("log list", lambda out: "numLogs 1" in out, "log list")
            run("log download 0 flight.ulg", lambda out: "Finished downloading flight.ulg" in out, "log download")
            run("ftp list /fs/microsd/log", lambda out: "Total size" in out.split("Listing /fs/microsd/log")[-1],
                "ftp listing")
            run("ftp get @PARAM/param.pck", lambda out: "ftp open failed" in out, "ftp refusal")
    out = mp.output
    print(out)
    # MAVProxy re-requests what has not come within its own timer (a loaded machine: "1 retries"), so the
    # download is judged by what arrived: every byte it counted is in the file, and the file is a whole ULog
    assert "Log 0  numLogs 1 lastLog 0 size" in out
    got = int(out.split("Finished downloading flight.ulg (", 1)[1].split(" bytes", 1)[0])
    assert got == (tmp_path / "flight.ulg").stat().st_size > 0
    day = out.split("Listing /fs/microsd/log")[1].split("Total size")[0].split()
    assert day[0] == "D" and len(day[1]) == 10  # one folder, YYYY-MM-DD
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):  # pyulog prints its warnings
        ulog = ULog(str(tmp_path / "flight.ulg"))  # log 0 is the vehicle's ULog, as on PX4
    assert printed.getvalue() == "" and not ulog.file_corruption
    assert len(ulog.get_dataset("vehicle_local_position").data["timestamp"]) > 5


def test_mavproxy_nsh_module_runs_shell_commands():
    # MAVProxy's `nsh` module (SERIAL_CONTROL, device SHELL; lines sent with "\r\n", output printed as it comes)
    api, gcs_port = free_udp_port(), free_udp_port()
    with VehicleProcess(api, gcs_port, []):
        with MavProxy(gcs_port) as mp:
            mp.wait_for("Detected vehicle 1:1", "vehicle detected")
            mp.send("module load nsh")
            mp.wait_for("Loaded module nsh")
            mp.send("nsh start")
            mp.send("ver all")
            mp.wait_for("INFO  [ver] UNKNOWN MCU", "ver all's last line")
            mp.send("param set MIS_TAKEOFF_ALT 4")
            mp.wait_for("-> new: 4.0000", "the shell's param set")
            mp.send("top")
            mp.wait_for("Invalid command: top", "pxh's answer to a command it has not")
            mp.send(".")  # leaves the shell (MAVProxy sends SERIAL_CONTROL without RESPOND: the shell closes)
            mp.send("param fetch MIS_TAKEOFF_ALT")  # MAVProxy's own parameter protocol
            mp.wait_for(lambda out: "MIS_TAKEOFF_ALT = 4.0" in out.split("Invalid command: top")[-1], "param fetch")
    out = mp.output
    print(out)
    assert "INFO  [ver] PX4 version: Release 1.14.0 (17694975)\n" in out  # what AUTOPILOT_VERSION announces
    # (the echoed "\r\n" MAVProxy ends lines with reads back as one newline: its output is read as text)
    assert "pxh> param set MIS_TAKEOFF_ALT 4\n  MIS_TAKEOFF_ALT: curr: 2.5000 -> new: 4.0000\npxh> " in out
    assert "pxh> top\nInvalid command: top\ntype 'help' for a list of commands\npxh> " in out
