"""MAVSDK-Python's own example scripts, unchanged, against `radseek vehicle` (PX4-SITL parity).

The examples (../shared/mavsdk-python-examples, BSD-3, never edited) use the gRPC MAVSDK-Python API
(`from mavsdk import System`), i.e. `mavsdk<4` (3.x, the deprecated name of `mavsdk-grpc`, bundling
mavsdk_server). radseek's own venv has the native `mavsdk` 4.x binding, under the same import name, so
the examples run from their own venv, `.venv-mavsdk-grpc/` (made by `make`; made here if missing).

Each example connects to `udpin://0.0.0.0:14540` and its mavsdk_server takes gRPC port 50051. The runner
moves both to free ports, as a second PX4 SITL instance moves its own (tests/support/example_ports.py: the
script is unchanged), so examples run side by side on both pytest workers. A pymavlink
listener on the vehicle's GCS port records what the vehicle did (sim time, position, mode), so the
asserts are on events and the vehicle's state, not on wall-clock durations. Examples that never end
(goto, telemetry) are stopped once the awaited event has happened. Examples that mostly sleep (orbit, offboard,
takeoff) run on a sped-up clock (tests/support/run_sped_up.py): the vehicle FACTOR times faster and their own
sleeps shorter, so each sleep spans the same simulated time as at 1x: FACTOR times shorter, or (``sim_clock``)
until the vehicle's clock, as the listener last saw it, has advanced by the sleep, however fast the vehicle
managed to run on a loaded machine.
"""

from __future__ import annotations

import importlib
import importlib.util
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as M

from benchmarks.shared_data import shared_path
from tests.conftest import free_port
from tests.support.example_ports import GRPC_ENV, MAVLINK_ENV
from vehicle_sim.harness import Gcs, VehicleProcess, free_udp_port

pytestmark = [pytest.mark.slow, pytest.mark.io]
REPO = Path(__file__).resolve().parents[1]
EXAMPLES = shared_path("mavsdk-python-examples")
VENV = Path(os.environ.get("RADSEEK_MAVSDK_GRPC_VENV", REPO / ".venv-mavsdk-grpc"))
WAIT_S = 240.0  # bounds waiting only
HOME = (47.397742, 8.545594, 488.0)
SIM_CLOCK_ENV = "RADSEEK_SIM_CLOCK_FILE"  # tests/support/run_sped_up.py reads the vehicle's clock there
#: the example venv's packages, as the Makefile installs them: the gRPC MAVSDK-Python, and what upload_params.py and
#: offboard_from_csv.py import besides (anyio, tqdm)
GRPC_VENV_PACKAGES = ("mavsdk>=3.15,<4", "anyio", "tqdm")


def grpc_python() -> Path:
    """The example venv's python with the gRPC MAVSDK-Python (3.x) installed; created if missing."""
    py = VENV / "bin" / "python"
    probe = [str(py), "-c", "import anyio, tqdm, mavsdk, sys; from mavsdk import System; "
                            "sys.exit(mavsdk.__file__ is None)"]
    if py.exists() and subprocess.run(probe, capture_output=True).returncode == 0:
        return py
    subprocess.run([sys.executable, "-m", "venv", str(VENV)], check=True)
    subprocess.run([str(py), "-m", "pip", "install", "--quiet", *GRPC_VENV_PACKAGES], check=True)
    return py


@dataclass
class Watch:
    """What the vehicle reported on the GCS port while an example ran."""

    positions: list = field(default_factory=list)  # (t_s, lat, lon, rel_alt_m)
    modes: set = field(default_factory=set)  # PX4 custom modes seen in HEARTBEATs
    mode_since: dict = field(default_factory=dict)  # custom mode -> sim s of the last position before it
    texts: list = field(default_factory=list)
    armed_seen: bool = False
    gps_fix: list = field(default_factory=list)  # GPS_RAW_INT fix types in order
    clock: Path | None = None  # where the vehicle's latest time_boot_ms (s) is written for the runner (sim_clock)

    def near(self, lat: float, lon: float, alt: float, tol_m: float) -> bool:
        return any(_dist_m(p[1], p[2], lat, lon) < tol_m and abs(p[3] - alt) < tol_m for p in self.positions)

    def max_alt(self) -> float:
        return max((p[3] for p in self.positions), default=0.0)


def _dist_m(lat1, lon1, lat2, lon2) -> float:
    n = math.radians(lat1 - lat2) * 6378137.0
    e = math.radians(lon1 - lon2) * 6378137.0 * math.cos(math.radians(lat2))
    return math.hypot(n, e)


def _listen(gcs: Gcs, watch: Watch, stop: threading.Event) -> None:
    while not stop.is_set():
        for m in gcs.poll(0.05):
            kind = m.get_type()
            if kind == "GLOBAL_POSITION_INT":
                watch.positions.append((m.time_boot_ms / 1000, m.lat / 1e7, m.lon / 1e7, m.relative_alt / 1000))
                if watch.clock is not None:
                    tmp = watch.clock.with_suffix(".tmp")
                    tmp.write_text(repr(m.time_boot_ms / 1000))
                    os.replace(tmp, watch.clock)  # the runner never reads half a number
            elif kind == "HEARTBEAT":
                watch.modes.add(m.custom_mode)
                watch.mode_since.setdefault(m.custom_mode, watch.positions[-1][0] if watch.positions else 0.0)
                watch.armed_seen |= bool(m.base_mode & 128)
            elif kind == "STATUSTEXT":
                watch.texts.append(m.text)
            elif kind == "GPS_RAW_INT":
                watch.gps_fix.append(m.fix_type)


def run_example(script: str, vehicle_args: list[str], *, expect: list[str], until=None,
                timeout: float = WAIT_S, runner: list[str] | None = None, cwd: Path | None = None,
                ports: dict[str, str] | None = None, sim_clock: bool = False, script_args: tuple[str, ...] = (),
                during=None) -> tuple[str, Watch, int | None]:
    """Run ``script`` unchanged (cwd = the examples folder, or ``cwd`` for one that writes files) against a fresh
    vehicle. Returns its output, the vehicle's watch and the exit code (None when stopped by us after
    ``until(output, watch)``). ``runner`` replaces the example venv's python (e.g. the mavsdk_grpc shim in
    radseek's own venv). ``ports``: the example's (``example_ports``), else free ones. ``sim_clock``: the runner
    (``sped_up``) is told the vehicle's clock, and the script's sleeps span simulated time whatever the load.
    ``script_args``: the example's own command line. ``during(gcs)``: called once, when every ``expect`` line is out,
    to act on the vehicle from its GCS port beside the example (send only: the listener reads that socket)."""
    runner = runner or sped_up(1)
    gcs_port = free_udp_port()
    ports = ports or example_ports()
    watch, stop = Watch(), threading.Event()
    clock_dir = tempfile.TemporaryDirectory(prefix="radseek-sim-clock-") if sim_clock else None
    if clock_dir is not None:
        watch.clock = Path(clock_dir.name) / "time_boot_s"
    with VehicleProcess(int(ports[MAVLINK_ENV]), gcs_port, vehicle_args) as vp, Gcs(gcs_port) as gcs:
        listener = threading.Thread(target=_listen, args=(gcs, watch, stop), daemon=True)
        listener.start()
        env = {**os.environ, "PYTHONUNBUFFERED": "1", **ports}
        if watch.clock is not None:
            env[SIM_CLOCK_ENV] = str(watch.clock)
        proc = subprocess.Popen([*runner, str(EXAMPLES / script), *script_args], cwd=cwd or EXAMPLES,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        lines: list[str] = []
        reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)
        reader.start()
        deadline = time.monotonic() + timeout
        code = None
        try:
            while True:
                out = "".join(lines)
                if during is not None and all(e in out for e in expect):
                    during(gcs)
                    during = None
                if until is not None and all(e in out for e in expect) and until(out, watch):
                    break
                code = proc.poll()
                if code is not None:
                    break
                if time.monotonic() > deadline:
                    break
                time.sleep(0.1)
        finally:
            if proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(15)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
            reader.join(10)
            stop.set()
            listener.join(5)
            if clock_dir is not None:
                clock_dir.cleanup()
    out = "".join(lines)
    print(f"--- {script} (exit {code}):\n{out[-4000:]}\n--- vehicle:\n{vp.output[-2000:]}\n--- texts: {watch.texts}")
    for e in expect:
        assert e in out, f"{script}: {e!r} not printed"
    return out, watch, code


def example_ports() -> dict[str, str]:
    """Free ports for one example's MAVLink (instead of 14540) and mavsdk_server gRPC (instead of 50051), as the
    environment of its runner (tests/support/example_ports.py moves them there; the script is unchanged)."""
    return {MAVLINK_ENV: str(free_udp_port()), GRPC_ENV: str(free_port())}


def sped_up(factor: int) -> list[str]:
    """The runner of an example whose sleeps are ``factor`` times shorter (the vehicle must run ``factor`` times
    faster than at 1x for the same simulated flight)."""
    return [str(grpc_python()), "-u", str(Path(__file__).parent / "support" / "run_sped_up.py"), str(factor)]


def completes(script: str, args: list[str], expect: list[str], runner: list[str] | None = None,
              cwd: Path | None = None, ports: dict[str, str] | None = None, sim_clock: bool = False
              ) -> tuple[str, Watch]:
    out, watch, code = run_example(script, args, expect=expect, runner=runner, cwd=cwd, ports=ports,
                                   sim_clock=sim_clock)
    assert code == 0, f"{script} did not complete (exit {code})"
    assert "Traceback" not in out, out
    return out, watch


def test_do_orbit():
    # on a 10x clock whose sleeps wait on the vehicle's own clock (sim_clock): with sleeps only 10x shorter in
    # wall time, a vehicle held below 10x on a loaded machine flew 20-35 s of the 60 s orbit, sometimes too
    # short to reach the circle 44 m away at 3 m/s (twice: none of its positions on it)
    out, w = completes("do_orbit.py", ["--speedup", "10"], ["--- Taking Off", "Do orbit at 10m height from the ground",
                                                            "--- Landing"], runner=sped_up(10), sim_clock=True)
    center = (47.398036222362471, 8.5450146439425509)
    on_circle = [p for p in w.positions if abs(_dist_m(p[1], p[2], *center) - 10.0) < 0.5 and abs(p[3] - 10) < 0.5]
    assert len(on_circle) > 20, "never flew on the 10 m circle at 10 m"
    assert (3 << 16 | 1 << 24) in w.modes  # PX4 POSCTL.ORBIT
    assert any("Orbit: circling" in t for t in w.texts)


def test_takeoff_and_land():
    # as at --speedup 2 with the script's own clock: its 10 s wait is 20 s of flight
    out, w = completes("takeoff_and_land.py", ["--speedup", "10"], ["-- Connected to drone!", "-- Taking off",
                                                                     "-- Landing"], runner=sped_up(5))
    assert w.max_alt() > 2.0  # MIS_TAKEOFF_ALT 2.5 m


def test_goto_reaches_the_location():
    target = (47.397606, 8.543060, 20.0)
    out, w, code = run_example("goto.py", ["--speedup", "10"], expect=["-- Taking off", "Staying connected"],
                               until=lambda out, w: w.near(*target, tol_m=1.0))
    assert w.near(*target, tol_m=1.0), f"never reached {target}: last {w.positions[-1:]}"


def test_telemetry_gps_info_yields_the_gps_denied_state():
    out, w, code = run_example("telemetry.py", [], expect=["GPS info:", "Battery:", "In air: False"],
                               until=lambda out, w: "latitude_deg" in out)
    assert "num_satellites: 0" in out and "fix_type: NO_FIX" in out  # honest: GPS-denied


def test_mission_flies_and_returns():
    out, w = completes("mission.py", ["--speedup", "10"], ["-- Uploading mission", "-- Starting mission",
                                                           "Mission progress: 3/3"])
    assert w.near(47.398036222362471, 8.5450146439425509, 25.0, tol_m=1.0)
    assert w.positions[-1][3] < 0.2 and _dist_m(*w.positions[-1][1:3], *HOME[:2]) < 1.0  # RTL: landed home


def test_mission_raw_upload():
    out, w = completes("mission_raw.py", [], ["-- Uploading mission", "-- Done"])


def test_mission_import_with_rally_points():
    out, w = completes("mission_import.py", [], ["5 mission items and2 rally items imported.", "Mission uploaded"])
    assert any("Rally: 2 point(s) uploaded" in t for t in w.texts)


def test_geofence_upload():
    out, w = completes("geofence.py", [], ["Geofence uploaded!"])
    assert any("Geofence: 2 zone(s) uploaded" in t for t in w.texts)


def test_offboard_position_ned():
    out, w = completes("offboard_position_ned.py", ["--speedup", "5"], ["-- Starting offboard", "-- Stopping offboard"],
                       runner=sped_up(5), sim_clock=True)
    assert "failed" not in out
    assert 4.5 < w.max_alt() < 5.5  # climbed to 5 m
    assert w.near(HOME[0] + 5 / 111_194.9, HOME[1] + 10 / (111_194.9 * math.cos(math.radians(HOME[0]))), 5.0, 0.5)
    assert 6 << 16 in w.modes  # PX4 OFFBOARD


def test_offboard_velocity_ned():
    out, w = completes("offboard_velocity_ned.py", ["--speedup", "5"], ["-- Starting offboard", "-- Go up 2 m/s",
                                                                         "-- Stopping offboard"], runner=sped_up(5),
                       sim_clock=True)
    assert "failed" not in out
    assert w.max_alt() > 5.0  # 4 s at 2 m/s up
    assert 6 << 16 in w.modes


def test_grpc_api_beside_the_native_4x_in_radseek_venv():
    """The other supported combination: `mavsdk-grpc` (import name `mavsdk_grpc`) installed in radseek's
    own venv next to the native `mavsdk` 4.x; the unchanged example runs with `mavsdk` resolved to
    `mavsdk_grpc` (tests/support/run_as_mavsdk_grpc.py), as an integrator's `import mavsdk_grpc as mavsdk`."""
    native = importlib.import_module("mavsdk.asyncio")  # `mavsdk` here is still the native binding radseek uses
    assert hasattr(native, "Mavsdk") and importlib.util.find_spec("mavsdk_grpc") is not None
    shim = Path(__file__).parent / "support" / "run_as_mavsdk_grpc.py"
    out, w = completes("mission_raw.py", [], ["-- Uploading mission", "-- Done"],
                       runner=[sys.executable, "-u", str(shim)])


FOLLOW_TARGET_MODE = 4 << 16 | 8 << 24  # PX4 AUTO.FOLLOW_TARGET


def test_follow_me_follows_the_target():
    # the example sets FLW_TGT_* (the altitude mode is an INT32), takes off, starts follow-me and sends three
    # target positions 2 s apart, the first 33 m north of home, the next two 43 m west of it, at 480 m AMSL
    # on a 5x clock, its 27 s of sleeps waiting on the vehicle's clock (sim_clock)
    out, w = completes("follow_me_example.py", ["--speedup", "5"], ["-- Starting Follow Me Mode", "-- Following Target",
                                                                     "-- Stopping Follow Me Mode", "-- Landing"],
                       runner=sped_up(5), sim_clock=True)
    assert FOLLOW_TARGET_MODE in w.modes
    start = next(p for p in w.positions if p[3] > 2.0)  # in the air, before following
    # 3D tracking (TARGET_GPS): 8 m above a target 8 m below home is home's height, so PX4's 1 m minimum safety
    # altitude holds it; towards the targets, north then west
    north = max((p for p in w.positions), key=lambda p: p[1])
    west = min((p for p in w.positions), key=lambda p: p[2])
    assert _dist_m(north[1], start[2], start[1], start[2]) > 5.0, "never went north towards the target"
    assert _dist_m(start[1], west[2], start[1], start[2]) > 2.0, "never went west towards the target"
    assert min(p[3] for p in w.positions if p[0] > start[0] + 10) < 2.0  # down towards the 1 m floor


def test_manual_control_moves_the_vehicle_in_position_mode():
    # the example flies random stick inputs forever at 10 Hz in POSCTL (x forward, y right, z throttle 0..1000
    # with 500 holding the altitude, r yaw): stopped once the sticks have moved the vehicle 2 m from where they began
    def moved(out, w):
        t0 = w.mode_since.get(3 << 16)
        if "-- Starting manual control" not in out or t0 is None:
            return False
        start = next((p for p in w.positions if p[0] >= t0), None)
        return start is not None and any(_dist_m(p[1], p[2], start[1], start[2]) > 2.0 or abs(p[3] - start[3]) > 2.0
                                         for p in w.positions if p[0] > t0)

    # on a 5x clock (its sleeps and the vehicle both 5x faster: the same simulated flight in a fifth of the time)
    out, w, code = run_example("manual_control.py", ["--speedup", "5"], expect=["-- Taking off",
                                                                             "-- Starting manual control"],
                               until=moved, runner=sped_up(5))
    assert 3 << 16 in w.modes  # PX4 POSCTL
    assert moved(out, w), "the sticks never moved the vehicle"


def test_all_params_lists_the_px4_parameters():
    out, w = completes("all_params.py", [], ["MIS_TAKEOFF_ALT: 2.5", "SYS_FAILURE_EN: 0"])
    assert "FLW_TGT_ALT_M: 0" in out  # an INT32 printed as one (PX4's type)


def test_firmware_version_is_px4s():
    out, w = completes("firmware_version.py", [], ["Version: [flight_sw_major: 1, flight_sw_minor: 14"])


def test_upload_params_from_a_qgc_params_file(tmp_path):
    # QGC's parameter file format (tab-separated: vehicle, component, name, value, MAV_PARAM_TYPE); MAVSDK's
    # set_param reads back what the vehicle answers, so a value the vehicle did not take fails the example
    params = tmp_path / "radseek.params"
    params.write_text("# Onboard parameters for Vehicle 1\n#\n# Vehicle-Id\tComponent-Id\tName\tValue\tType\n"
                      "1\t1\tMIS_TAKEOFF_ALT\t4.5\t9\n1\t1\tFLW_TGT_ALT_M\t1\t6\n1\t1\tNO_SUCH_PARAM\t1\t9\n")
    out, w, code = run_example("upload_params.py", [], expect=["Connected to the Vehicle", "Params uploaded!"],
                               script_args=("udpin://0.0.0.0:14540", str(params)))
    assert code == 0 and "Traceback" not in out  # the unknown name is skipped by the example, as on PX4


@pytest.mark.parametrize("script, line", [("telemetry_flight_mode.py", "FlightMode: HOLD"),
                                          ("telemetry_is_armed_is_in_air.py", "Is_armed: False")])
def test_telemetry_streams_print(script, line):
    out, w, code = run_example(script, [], expect=[], until=lambda out, w: out.count(line) >= 3)
    assert out.count(line) >= 3 and "Traceback" not in out


def test_telemetry_status_text_prints_the_vehicles_texts():
    # it prints each STATUSTEXT; nothing is said on the ground until something happens: a calibration is asked
    # for beside it (MAVLink from the GCS port), and its [cal] texts must come out of the example
    def asked(out, w):
        return "StatusText" in out and "calibration started: 2 gyro" in out

    out, w, code = run_example("telemetry_status_text.py", [], expect=["-- Connected to drone!"], until=asked,
                               during=lambda gcs: gcs.send(M.MAVLink_command_long_message(
                                   1, 1, M.MAV_CMD_PREFLIGHT_CALIBRATION, 0, 1, 0, 0, 0, 0, 0, 0)))
    assert asked(out, w)


def test_telemetry_takeoff_and_land():
    out, w = completes("telemetry_takeoff_and_land.py", ["--speedup", "5"], ["-- Taking off", "Flight mode: TAKEOFF",
                                                                            "-- Landing", "Flight mode: LAND"],
                       runner=sped_up(5), sim_clock=True)
    assert 9.5 < w.max_alt() < 10.5 and w.positions[-1][3] < 0.2  # takeoff altitude set to 10 m, landed


def test_offboard_position_velocity_ned():
    out, w = completes("offboard_position_velocity_ned.py", ["--speedup", "5"], ["-- Starting offboard",
                                                                                "-- Stopping offboard"],
                       runner=sped_up(5), sim_clock=True)
    assert "failed" not in out and 6 << 16 in w.modes
    assert 9.5 < w.max_alt() < 10.5  # 10 m up


def test_offboard_velocity_body():
    out, w = completes("offboard_velocity_body.py", ["--speedup", "5"], ["-- Turn clock-wise and climb",
                                                                        "-- Stopping offboard"],
                       runner=sped_up(5), sim_clock=True)
    assert "failed" not in out and 6 << 16 in w.modes and w.max_alt() > 2.0
