"""The MAVLink shell (SERIAL_CONTROL, device SHELL) of the vehicle over real UDP, with a bare pymavlink ground station:
PX4 SITL's pxh framing (echo, ``pxh> `` after each line, replies flagged REPLY in 70-byte pieces), its commands
answered from the vehicle's state and parameter store (the same one PARAM_SET and PARAM_REQUEST_READ see), and the
transport rules of PX4's mavlink module (a message without RESPOND closes the shell; REPLY-flagged, other-device and
over-long messages are not taken). Every exchange ends at the prompt, so nothing waits on wall time."""

import json
import re
import subprocess
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as M

from tests.conftest import free_port
from tests.test_mavsdk_examples import grpc_python
from vehicle_sim.harness import Gcs, VehicleProcess, VehicleThread, free_udp_port, thread_config
from vehicle_sim.navigator import Mode, px4_custom_mode

pytestmark = pytest.mark.io
RESPOND = M.SERIAL_CONTROL_FLAG_RESPOND | M.SERIAL_CONTROL_FLAG_EXCLUSIVE  # what mavlink_shell.py sends
WAIT_S = 30.0  # bounds waiting only


@pytest.fixture
def gcs():
    gcs_port = free_udp_port()
    with VehicleThread(thread_config(free_udp_port(), gcs_port, speedup=5.0)), Gcs(gcs_port) as g:
        g.wait_vehicle()
        yield g


def send(gcs: Gcs, text: str, flags: int = RESPOND, device: int = M.SERIAL_CONTROL_DEV_SHELL) -> None:
    data = text.encode()
    for i in range(0, len(data), 70):
        chunk = data[i:i + 70]
        gcs.send(M.MAVLink_serial_control_message(device, flags, 0, 0, len(chunk), list(chunk.ljust(70, b"\x00"))))


def shell(gcs: Gcs, text: str, prompts: int = 1) -> tuple[str, list]:
    """Send ``text`` with RESPOND; the output up to its ``prompts``-th prompt, and the replies that carried it."""
    send(gcs, text)
    out, replies = "", []
    deadline = time.monotonic() + WAIT_S
    while out.count("pxh> ") < prompts:
        assert time.monotonic() < deadline, f"no prompt after {text!r}: {out!r}"
        for m in gcs.poll(0.05):
            if m.get_type() == "SERIAL_CONTROL":
                replies.append(m)
                out += bytes(m.data[:m.count]).decode()
    return out, replies


def test_pxh_over_serial_control_answers_from_the_vehicle(gcs):
    out, _ = shell(gcs, "\n")
    assert out == "\npxh> "  # no prompt before the first newline (PX4 SITL's pxh); clients send one to get it
    out, replies = shell(gcs, "ver all\n")
    assert out.startswith("ver all\n")  # the line echoed, then its output, then the prompt
    assert "INFO  [ver] HW arch: PX4_SITL\n" in out and out.endswith("INFO  [ver] UNKNOWN MCU\npxh> ")
    assert len(replies) > 1 and all(m.count <= 70 for m in replies)  # several SERIAL_CONTROLs of <= 70 bytes
    assert {(m.device, m.flags) for m in replies} == {(M.SERIAL_CONTROL_DEV_SHELL, M.SERIAL_CONTROL_FLAG_REPLY)}
    # the version AUTOPILOT_VERSION announces; PX4 puts its git hash's first 8 bytes (as a little-endian number) in
    # flight_custom_version, which MAVSDK and QGroundControl print back byte-reversed
    gcs.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    av = gcs.recv("AUTOPILOT_VERSION")
    v = av.flight_sw_version
    assert f"PX4 version: Release {v >> 24}.{v >> 16 & 255}.{v >> 8 & 255} ({v})\n" in out
    assert f"PX4 git-hash: {bytes(av.flight_custom_version)[::-1].hex()}\n" in out

    # parameters: the store PARAM_SET and PARAM_REQUEST_READ use, with its bounds and read-only rule
    out, _ = shell(gcs, "param show mis_*\n")
    assert "\nx   MIS_TAKEOFF_ALT [0,0] : 2.5000\n" in out and "RTL_RETURN_ALT" not in out
    out, _ = shell(gcs, "param set MIS_TAKEOFF_ALT 4\n")
    assert "\n  MIS_TAKEOFF_ALT: curr: 2.5000 -> new: 4.0000\npxh> " in out
    gcs.send(M.MAVLink_param_request_read_message(1, 1, b"MIS_TAKEOFF_ALT", -1))
    assert gcs.recv("PARAM_VALUE", lambda m: m.param_id == "MIS_TAKEOFF_ALT").param_value == 4.0
    out, _ = shell(gcs, "param show -c\n")
    assert "\nx * MIS_TAKEOFF_ALT [0,0] : 4.0000\n" in out and out.count(" : ") == 1  # changed since boot
    out, _ = shell(gcs, "param set MIS_TAKEOFF_ALT 500\n")
    assert "ERROR [param] Parameter MIS_TAKEOFF_ALT = 500 out of [0.5, 100].\nCommand 'param' failed" in out
    out, _ = shell(gcs, "param set SIM_SPEEDUP 2\n")
    assert "ERROR [param] Parameter SIM_SPEEDUP is read-only.\n" in out
    out, _ = shell(gcs, "param set FLW_TGT_ALT_M 1.5\n")
    assert "ERROR [param] Parameter FLW_TGT_ALT_M: '1.5' is not an integer.\n" in out
    out, _ = shell(gcs, "param show -q MIS_TAKEOFF_ALT\n")
    assert out == "param show -q MIS_TAKEOFF_ALT\n4.0000\npxh> "

    # what PX4 SITL's shell has and this one has not, said in pxh's words
    out, _ = shell(gcs, "uorb top\n")
    assert out == "uorb top\nInvalid command: uorb\ntype 'help' for a list of commands\npxh> "
    out, _ = shell(gcs, "help\n")
    assert "Builtin Commands:\n  commander\n  param\n  ver\npxh> " in out

    # commander: the vehicle's own state, and its own commands (takeoff: arm, then take off to MIS_TAKEOFF_ALT)
    out, _ = shell(gcs, "commander status\n")
    assert "INFO  [commander] Disarmed\nINFO  [commander] navigation mode: Hold\n" in out
    shell(gcs, "commander takeoff\n")
    hb = gcs.recv("HEARTBEAT", lambda m: m.custom_mode == px4_custom_mode(Mode.TAKEOFF))
    assert hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    out, _ = shell(gcs, "commander status\n")
    assert "INFO  [commander] Armed\n" in out
    gcs.recv("GLOBAL_POSITION_INT", lambda m: m.relative_alt > 3500)  # climbing to the 4 m just set


def test_transport_rules_of_px4s_mavlink_module(gcs):
    # a REPLY-flagged message, another device and a count above the 70 bytes of data are not taken
    send(gcs, "param set MIS_TAKEOFF_ALT 6\n", flags=RESPOND | M.SERIAL_CONTROL_FLAG_REPLY)
    send(gcs, "param set MIS_TAKEOFF_ALT 7\n", device=M.SERIAL_CONTROL_DEV_TELEM1)
    gcs.send(M.MAVLink_serial_control_message(M.SERIAL_CONTROL_DEV_SHELL, RESPOND, 0, 0, 71, list(b"x" * 70)))
    # bytes at or below 3 (ctrl-C) and above 127 are dropped, as pxh's signed char drops them
    out, _ = shell(gcs, "\x03param \xc3\xa9show -q MIS_TAKEOFF_ALT\n")
    assert out.endswith("\n2.5000\npxh> ")
    # without RESPOND the bytes still run, then the shell closes: the output is lost, and so is an unfinished line
    send(gcs, "param set MIS_TAKEOFF_ALT 3\nver", flags=0)
    out, _ = shell(gcs, " all\n")
    assert out == " all\nInvalid command: all\ntype 'help' for a list of commands\npxh> "
    gcs.send(M.MAVLink_param_request_read_message(1, 1, b"MIS_TAKEOFF_ALT", -1))
    assert gcs.recv("PARAM_VALUE", lambda m: m.param_id == "MIS_TAKEOFF_ALT").param_value == 3.0
    # a line longer than one message arrives in pieces and runs once whole
    out, _ = shell(gcs, "param show " + "X" * 80 + "\n")
    assert re.search(r"\n (\d+)/\1 parameters used\.\npxh> $", out) and out.count("pxh> ") == 1


@pytest.mark.slow
def test_mavsdk_pythons_shell_plugin_runs_commands():
    # the gRPC MAVSDK-Python 3.x of the upstream examples (.venv-mavsdk-grpc, its own mavsdk_server) on the API port
    api = free_udp_port()
    client = Path(__file__).parent / "support" / "mavsdk_shell_client.py"
    with VehicleProcess(api, free_udp_port()):
        run = subprocess.run([str(grpc_python()), str(client), str(api), str(free_port()), "--param", "MIS_TAKEOFF_ALT",
                              "ver all", "param set MIS_TAKEOFF_ALT 4"], capture_output=True, text=True, timeout=240)
    print(run.stdout, run.stderr)
    assert run.returncode == 0
    transcript, info = run.stdout.rstrip("\n").rsplit("\n", 1)
    info = json.loads(info)
    major, minor, patch = info["flight_sw"]
    assert "ver all\nINFO  [ver] HW arch: PX4_SITL\n" in transcript  # the command echoed, then its output
    # the version MAVSDK's info plugin read from AUTOPILOT_VERSION (its git hash: test_pxh_over_serial_control...)
    assert f"INFO  [ver] PX4 version: Release {major}.{minor}.{patch} (" in transcript
    assert "param set MIS_TAKEOFF_ALT 4\n  MIS_TAKEOFF_ALT: curr: 2.5000 -> new: 4.0000\npxh> " in transcript
    assert info["MIS_TAKEOFF_ALT"] == 4.0  # set in the shell, read back by the parameter protocol
