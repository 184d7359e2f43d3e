"""MAVSDK-Python's upstream examples beyond ../shared (github.com/mavlink/MAVSDK-Python, examples/, BSD-3),
unchanged, against `radseek vehicle`: the examples are the copies in tests/mavsdk_upstream/ (byte for byte, with
their licence and source commit), or those of the MAVSDK-Python checkout named by RADSEEK_MAVSDK_PYTHON_EXAMPLES.

They run as tests/test_mavsdk_examples.py runs the shared ones (same runner, each example on its own free ports):
a pymavlink listener on the vehicle's GCS port records what the vehicle did."""

from __future__ import annotations

import contextlib
import io
import math
import os
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from pyulog import ULog

from tests import test_mavsdk_examples as ex
from vehicle_sim.imu import ACCEL_NOISE_DENSITY, IMU_HZ

pytestmark = [pytest.mark.slow, pytest.mark.io]
UPSTREAM = Path(os.environ.get("RADSEEK_MAVSDK_PYTHON_EXAMPLES", Path(__file__).parent / "mavsdk_upstream"))


@pytest.fixture(autouse=True)
def upstream_examples(monkeypatch):
    if not (UPSTREAM / "failure_injection.py").exists():
        pytest.fail(f"MAVSDK-Python's examples folder not found at {UPSTREAM}: set RADSEEK_MAVSDK_PYTHON_EXAMPLES to "
                    "a checkout's examples/ (git clone https://github.com/mavlink/MAVSDK-Python)")
    monkeypatch.setattr(ex, "EXAMPLES", UPSTREAM)


def test_failure_injection_gps_off():
    # SYS_FAILURE_EN (INT32) set, take off, climb 20 m, GPS off, 20 s later failure injection disabled again
    expect = ["-- Enabling failure injection", "-- Injecting GPS failure", "-- Disabling failure injection"]
    out, w = ex.completes("failure_injection.py", ["--speedup", "5"], expect, runner=ex.sped_up(5))
    assert "Traceback" not in out
    assert any("Failure injected: gps off" in t for t in w.texts)
    assert w.max_alt() > 15.0  # flew up before the failure
    # the receiver, connected without a fix (GPS-denied) before, reports no GPS once failed
    assert w.gps_fix[0] == 1 and w.gps_fix[-1] == 0 and 1 in w.gps_fix[:w.gps_fix.index(0)]


@contextlib.contextmanager
def mavsdk_server(ports: dict[str, str], cwd: Path | None = None):
    """MAVSDK's own mavsdk_server (the example venv's binary) on the example's ports (``ex.example_ports``), for an
    example written to attach to a running one (``System(mavsdk_server_address="localhost", port=50051)``). ``cwd``:
    where it writes what the example downloads to "."."""
    py = ex.grpc_python()
    where = subprocess.run([str(py), "-c", "import mavsdk, os; print(os.path.dirname(mavsdk.__file__))"],
                           capture_output=True, text=True, check=True).stdout.strip()
    proc = subprocess.Popen([str(Path(where) / "bin" / "mavsdk_server"), "-p", ports[ex.GRPC_ENV],
                             f"udpin://0.0.0.0:{ports[ex.MAVLINK_ENV]}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=cwd)
    try:
        yield proc
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_ftp_list_dir_lists_the_vehicle_root():
    # the example attaches to a running mavsdk_server (its own connect() address, a serial port, is then unused)
    ports = ex.example_ports()
    with mavsdk_server(ports):
        out, w = ex.completes("ftp_list_dir.py", [], ["-- Connected to drone!", "directory list"], ports=ports)
    assert "directory list ListDirectoryData: [dirs: ['fs'], files: []]" in out


def test_logfile_download_fetches_the_flight_ulog(tmp_path):
    # the example writes ./log-<date>.ulog: run it in a scratch folder. On a 10x clock the vehicle's ULog (about
    # 3 kB a sim second) is usually past MAVSDK's 46 kB request by the time the example lists it
    out, w = ex.completes("logfile_download.py", ["--speedup", "10"],
                          ["-- Connected to drone!", "Log 0 from", "Downloading: log 0"], cwd=tmp_path)
    logs = list(tmp_path.glob("log-*.ulog"))
    assert len(logs) == 1, f"no log written: {list(tmp_path.iterdir())}"
    data = logs[0].read_bytes()
    assert data[:7] == b"ULog\x01\x12\x35"  # a ULog, as PX4 SITL serves log 0
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):  # pyulog prints its warnings
        ulog = ULog(io.BytesIO(data))
    assert printed.getvalue() == "" and not ulog.file_corruption
    assert {d.name for d in ulog.data_list} == {"vehicle_attitude", "vehicle_local_position", "sensor_combined",
                                                 "vehicle_global_position", "vehicle_status", "battery_status"}
    assert ulog.msg_info_dict["sys_name"] == "PX4" and ulog.msg_info_dict["ver_hw"] == "PX4_SITL"
    assert ulog.initial_parameters["SIM_SPEEDUP"] == 10.0 and ulog.initial_parameters["SYS_FAILURE_EN"] == 0
    assert ulog.initial_parameters["FLW_TGT_HT"] > 0 and len(ulog.initial_parameters) > 15
    seen = {round(t * 1e3): (lat, lon) for t, lat, lon, _ in w.positions}  # GLOBAL_POSITION_INT, by sim ms
    for d in ulog.data_list:  # sim time from boot, 50 ms steps, never back, never past what the GCS saw last
        ts = d.data["timestamp"].astype(np.int64)
        assert ts[0] == 0 and np.all(np.diff(ts) > 0) and np.all(ts % 50_000 == 0), d.name
        assert ts[-1] <= round(w.positions[-1][0] * 1e6), d.name
    gp = ulog.get_dataset("vehicle_global_position").data
    both = [(seen[t // 1000], (la, lo)) for t, la, lo in zip(gp["timestamp"], gp["lat"], gp["lon"], strict=True)
            if t // 1000 in seen]
    print(f"ULog {len(data)} bytes, {ts[-1] / 1e6:.2f} s of sim time, {len(both)} positions seen on both")
    assert both  # the same positions over MAVLink (1e-7 deg) and in the log (double), at the same sim times
    assert all(abs(a[0] - b[0]) <= 1e-7 and abs(a[1] - b[1]) <= 1e-7 for a, b in both)


def test_highres_imu_streams_at_the_requested_200_hz():
    # the example asks 200 Hz (set_rate_imu) and prints samples forever: stopped after 200 of them
    def enough(out, w):
        return out.count("HIGHRES_IMU (105)") >= 200

    out, w, code = ex.run_example("highres_imu.py", [], expect=["Drone is connected!", "Fetching IMU data..."],
                                  until=enough)
    assert "Traceback" not in out and enough(out, w)
    stamps = [int(line.split(":")[1]) for line in out.splitlines() if line.startswith("Time (us):")]
    steps = np.diff(stamps)
    # MAVSDK hands on every sample; at 1x the vehicle keeps 200 Hz of simulated time (loopback loses none)
    assert np.median(steps) == 5000 and (steps > 0).all() and np.mean(steps == 5000) > 0.95
    z = np.array([float(line.split(":")[1]) for line in out.splitlines() if line.startswith("Z Acceleration")])
    # standing on the ground: the specific force is -g on z, plus PX4 SITL's accelerometer noise (white, sigma per
    # sample at the IMU's 250 Hz: vehicle_sim.imu); bounds at ~1e-6 for ~200 samples
    sigma = ACCEL_NOISE_DENSITY * math.sqrt(IMU_HZ)
    assert len(z) >= 200 and abs(z.mean() + 9.80665) < 5 * sigma / math.sqrt(len(z))
    assert np.abs(z + 9.80665).max() < 6 * sigma and 0.65 < z.std(ddof=1) / sigma < 1.35


def test_offboard_attitude_flies_the_commanded_tilts():
    # arm, attitude offboard: 2 s level at 70 % thrust (up), 2 s rolled 30 deg right at 60 %, 2 s rolled 30 deg
    # left, 2 s level at 60 % (MPC_THR_HOVER), stop, land; on a 5x clock, each phase still 2 s of flight
    out, w = ex.completes("offboard_attitude.py", ["--speedup", "5"], ["-- Starting offboard", "-- Go up at 70% thrust",
                                                                        "-- Roll -30 at 60% thrust",
                                                                        "-- Stopping offboard"],
                          runner=ex.sped_up(5))
    assert "failed" not in out
    assert 6 << 16 in w.modes  # PX4 OFFBOARD
    home = w.positions[0]
    east = [ex._dist_m(home[1], p[2], home[1], home[2]) * (1 if p[2] > home[2] else -1) for p in w.positions]
    north = [ex._dist_m(p[1], home[2], home[1], home[2]) for p in w.positions]
    top = max(range(len(east)), key=east.__getitem__)
    print(f"east at most {east[top]:.1f} m, then back to {min(east[top:]):.1f} m; up to {w.max_alt():.1f} m")
    assert w.max_alt() > 1.0  # 70 % thrust climbed
    assert east[top] > 3.0, "rolling right never took it east"
    assert min(east[top:]) < east[top] - 3.0, "rolling left never brought it back west"
    assert max(north) < 0.5  # a roll about the north-pointing body x axis: no motion north or south


def test_calibration_gyro_done_then_accelerometer_fails_as_on_px4_sitl():
    # gyro, then accelerometer, magnetometer, level horizon, each to its end. A vehicle on the ground cannot be held
    # on its six sides: PX4 SITL's accelerometer calibration measures the down side, finds it again five times and
    # fails "timeout: no motion" (calibration_routines.cpp), and MAVSDK raises; the example stops there
    def failed(out, w):
        return "CalibrationError" in out

    out, w, code = ex.run_example("calibration.py", ["--speedup", "5"], until=failed,
                                  expect=["-- Starting gyroscope calibration", "-- Gyroscope calibration finished",
                                          "-- Starting accelerometer calibration"])
    assert "FAILED: 'Failed'; origin: calibrate_accelerometer()" in out
    gyro = out[out.index("-- Starting gyroscope"):out.index("-- Gyroscope calibration finished")]
    progress = [float(p) for p in re.findall(r"has_progress: True, progress: ([0-9.]+)", gyro)]
    assert progress and progress == sorted(progress) and progress[-1] == 1.0  # MAVSDK read every [cal] progress
    assert "status_text: down side done, rotate to a different side" in out  # the side it stands on was measured
    assert w.texts[-1] in ("[cal] calibration failed: accel", "[cal] calibration failed: timeout: no motion")
    assert sum(t == "[cal] down side already completed" for t in w.texts) == 5


def test_offboard_from_csv_flies_the_trajectory_and_lands_home():
    # 127 s of position + velocity setpoints at 10 Hz from active.csv (read from the example's folder): climb to
    # 15 m, out to ~18 m north and ~20 m east, back home, land; on a 5x clock whose sleeps wait on the vehicle's clock
    out, w = ex.completes("offboard_from_csv/offboard_from_csv.py", ["--speedup", "5"],
                          ["-- Starting offboard", "-- Performing trajectory", "Maneuvering (trajectory)",
                           "-- Shape completed", "-- Disarming"],
                          runner=ex.sped_up(5), cwd=UPSTREAM / "offboard_from_csv", sim_clock=True)
    assert "failed" not in out and 6 << 16 in w.modes  # PX4 OFFBOARD
    home = w.positions[0]
    far = max(ex._dist_m(p[1], p[2], home[1], home[2]) for p in w.positions)
    print(f"up to {w.max_alt():.1f} m, out to {far:.1f} m; last {w.positions[-1]}")
    assert 14.0 < w.max_alt() < 16.0 and far > 15.0
    last = w.positions[-1]
    assert last[3] < 0.2 and ex._dist_m(last[1], last[2], home[1], home[2]) < 1.0  # landed home


def test_mavlink_direct_receive_reads_attitude_as_json():
    # MAVSDK's MavlinkDirect plugin decodes any message by its XML definition: ATTITUDE from system 1, component 1
    def three(out, w):
        return out.count("ATTITUDE from 1/1:") >= 3

    out, w, code = ex.run_example("mavlink_direct_receive.py", [], expect=["-- Connected to drone!"], until=three)
    assert three(out, w) and "Traceback" not in out
    stamps = [int(s) for s in re.findall(r'"time_boot_ms": (\d+)', out)]
    assert len(stamps) >= 3 and stamps == sorted(stamps) and len(set(stamps)) == len(stamps)


@pytest.mark.parametrize("script, expect", [
    ("mavlink_direct_send.py", ["-- Connected to drone!", "Sending airspeed 19..."]),  # a custom-XML message
    ("tune.py", ["-- Connected to drone!", "Tune played"]),  # PLAY_TUNE_V2: nothing to play it, as a SITL
    ("send_status_message.py", ["-- Connected to drone!"]),  # a STATUSTEXT from MAVSDK's server utility
    ("rtcm.py", []),  # GPS_RTCM_DATA: no receiver to correct (GPS-denied), taken and ignored
])
def test_examples_that_send_and_end(script, expect):
    out, w = ex.completes(script, [], expect)


def test_transponder_waits_for_traffic():
    # ADSB_VEHICLE: no traffic is simulated (nor in PX4 SITL unless its fake-traffic generator runs); the example
    # prints its waiting line every second and nothing breaks
    def waited(out, w):
        return out.count("Waiting for transponder messages") >= 3

    out, w, code = ex.run_example("transponder.py", [], expect=[], until=waited)
    assert waited(out, w) and "Traceback" not in out and "Transponder" not in out.replace("transponder messages", "")


def test_px4_ev_automation_runs_its_schedule():
    # 5 s then 10 s between its three parameter sets (printed, not sent: the example only reads the landed state),
    # then the flight mode; on a 5x clock
    def hold(out, w):
        return "Setting EV params..." in out and "Flight Mode: HOLD" in out.split("Setting EV params...")[1]

    out, w, code = ex.run_example("px4_ev_automation.py", ["--speedup", "5"], runner=ex.sped_up(5), until=hold,
                                  expect=["Setting preflight params...", "Setting GPS params...",
                                          "Landed state: ON_GROUND"])
    assert hold(out, w) and "Traceback" not in out


def test_ftp_download_file_of_a_file_sitl_has_not_fails_fast(tmp_path):
    # it asks for /etc/extras/px4_io-v2_default.bin, the IO coprocessor's firmware, which only boards with a PX4IO
    # carry (PX4 SITL has none either): the vehicle's FTP server says FileNotFound at once, MAVSDK raises
    ports = ex.example_ports()
    with mavsdk_server(ports, cwd=tmp_path):  # mavsdk_server opens the local file before asking
        out, w, code = ex.run_example("ftp_download_file.py", [], expect=["-- Connected to drone!"], ports=ports)
    assert code == 1 and "FILE_DOES_NOT_EXIST" in out and "/etc/extras/px4_io-v2_default.bin" in out
