"""The CLI keeps its promises (issue 16): the zenoh-cli recipe of docs/topics.md works as written, the
inspection tools say at once when no router answers, a port in use is named with the flag that moves
it, and `radseek plan` runs with no arguments. Real processes on loopback."""

import json
import shlex
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from radseek import topics
from radseek.zenoh_session import open_session
from radseek_cli.inspect_cli import ZENOH_CLI_COMMAND
from tests.conftest import free_port

RADSEEK = [sys.executable, "-m", "radseek_cli"]
WAIT_S = 60.0  # bounds waiting only


def test_zenoh_cli_recipe_prints_decoded_json(router):
    # beside a real detector emulator (its own clock): JSON histograms and status, and binary raw frames, which the
    # recipe must leave out rather than print a traceback for each (issue 33: radseek/** did, 10 a second)
    port = router.rsplit(":", 1)[1]
    cmd = shlex.split(ZENOH_CLI_COMMAND.replace("7447", port))  # the documented command, on this router
    cmd[0] = str(Path(sys.executable).parent / "zenoh")
    sub = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(sub.stdout), daemon=True)
    reader.start()
    detector = subprocess.Popen([*RADSEEK, "detector", "--clock", "own", "--pose", "0,0,1,0", "--connect", router],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    raw: list[bytes] = []
    session = open_session(None, router)
    session.declare_subscriber(topics.key(topics.RAW_FRAME), lambda sample: raw.append(sample.payload.to_bytes()))
    try:
        deadline = time.monotonic() + WAIT_S
        while sum(ln.startswith("radseek/uav0/detector/histogram ") for ln in lines) < 20 or len(raw) < 20:
            assert sub.poll() is None, "".join(lines)
            assert detector.poll() is None, detector.stdout.read()
            assert time.monotonic() < deadline, f"zenoh-cli printed no 20 histograms:\n{''.join(lines)}"
            time.sleep(0.1)
    finally:
        session.close()
        for proc in (detector, sub):
            proc.terminate()
            proc.wait(10)
        reader.join(5)
    out = "".join(lines)
    assert "Traceback" not in out and "ERROR" not in out, out[-2000:]
    line = next(ln for ln in lines if ln.startswith("radseek/uav0/detector/histogram "))
    assert len(json.loads(line.split(" ", 1)[1])["counts"]) == topics.N_CHANNELS  # JSON, not base64
    assert any(ln.startswith("radseek/uav0/sim/clock ") for ln in lines)
    assert not any("/detector/raw" in ln for ln in lines)  # the raw frames went by, left out


@pytest.mark.io
def test_topics_and_echo_say_when_no_router_answers():
    nobody = f"tcp/127.0.0.1:{free_port()}"
    for cmd in (["topics"], ["echo", "sim/clock"]):
        proc = subprocess.run([*RADSEEK, *cmd, "--connect", nobody], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 1
        assert f"no zenoh router at {nobody} after 3 s" in proc.stderr and "radseek router" in proc.stderr


def test_router_port_in_use_is_named_with_the_flag(router):
    proc = subprocess.run([*RADSEEK, "router", "--listen", router], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1
    assert f"{router} is already in use" in proc.stderr and "--listen" in proc.stderr


@pytest.mark.io
def test_vehicle_port_in_use_is_named_with_the_flag():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as held:
        held.bind(("127.0.0.1", 0))
        port = held.getsockname()[1]
        proc = subprocess.run([*RADSEEK, "vehicle", "--no-zenoh", "--api-local-port", str(port),
                               "--gcs-local-port", "0", "--duration", "1"], capture_output=True, text=True,
                              timeout=120)
    assert proc.returncode == 2
    assert f"UDP port {port}" in proc.stderr and "--api-local-port" in proc.stderr


@pytest.mark.io
def test_plan_runs_with_no_arguments(tmp_path):
    proc = subprocess.run([*RADSEEK, "plan"], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "planning an exploration" in proc.stderr and "dwell point(s)" in proc.stdout


@pytest.mark.parametrize("bad", [["--speedup", "-5"], ["--speedup", "0"], ["--speedup", "5000"],
                                 ["--max-dwells", "0"]])
def test_run_refuses_invalid_options_before_starting_anything(bad, tmp_path, capsys):
    from radseek_cli import run_cli

    with pytest.raises(SystemExit) as exc:
        run_cli.main([*bad, "--out", str(tmp_path / "run")])
    assert exc.value.code == 2
    assert bad[0] in capsys.readouterr().err
    assert not (tmp_path / "run").exists()  # refused before the output folder (or any process) was made
