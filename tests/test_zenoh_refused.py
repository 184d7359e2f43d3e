"""A process whose zenoh credentials the router refuses stops at once with one line naming its user and the router's
endpoint, instead of flying on without zenoh (issue 34); `radseek run` then ends naming the refused process, with a
non-zero exit code, and keeps what it recorded. A real authenticated `radseek router` (the credentials `radseek run`
generates) and real processes; the fault injected is one role's wrong password (a credentials file, or a zenoh
JSON5 client config, as a hardware board would be given).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from detector_fw_sim.scene import load_scene
from launch.zenoh_auth import stack_env, write_run_credentials
from radseek.zenoh_auth import CREDENTIALS_ENV, read_credentials
from radseek_io.dataset import write_json
from tests.conftest import free_port
from vehicle_sim.harness import free_udp_port

EXIT_S = 120  # bound on a refused process's exit (a loaded host is slow); before the fix it never exits


@pytest.fixture
def auth_router(tmp_path):
    """`radseek router` admitting only the users of a run's credentials file; yields (endpoint, credentials)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    credentials = write_run_credentials(tmp_path / "router", ["uav0"], endpoint)
    proc = subprocess.Popen([sys.executable, "-m", "radseek_cli", "router", "--listen", endpoint],
                            env={**os.environ, **stack_env(credentials)}, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        line = proc.stdout.readline()
        assert "listening" in line and "admitting" in line, line
        yield endpoint, credentials
    finally:
        proc.terminate()
        proc.wait(60)


def _wrong_password(credentials: Path, user: str, folder: Path) -> Path:
    """A copy of ``credentials`` where ``user``'s password is wrong (every other line as the router has it)."""
    lines = [f"{u.name}:{'not-the-secret' if u.name == user else u.password}\n" for u in read_credentials(credentials)]
    assert sum(line.startswith(f"{user}:") for line in lines) == 1
    path = folder / "wrong-credentials"
    path.write_text("".join(lines))
    return path


def _command(role: str, endpoint: str, tmp_path: Path) -> list[str]:
    cmd = [sys.executable, "-m", "radseek_cli", role, "--connect", endpoint]
    if role == "vehicle":  # flies forever unless stopped
        return cmd + ["--api-port", str(free_udp_port()), "--gcs-port", str(free_udp_port()),
                      "--api-local-port", "0", "--gcs-local-port", "0"]
    if role == "detector":
        return cmd + ["--clock", "zenoh"]
    scenario = tmp_path / "scenario.json"
    write_json(scenario, load_scene("default").scenario().to_dict())
    return cmd + ["--scenario", str(scenario), "--out", str(tmp_path / "dataset"), "--connect-timeout", "600"]


@pytest.mark.io
@pytest.mark.parametrize("role", ["vehicle", "detector", "mission"])
def test_a_process_refused_by_the_router_stops_naming_its_user_and_the_router(auth_router, tmp_path, role):
    endpoint, credentials = auth_router
    wrong = _wrong_password(credentials, f"{role}@uav0", tmp_path)
    r = subprocess.run(_command(role, endpoint, tmp_path), env={**os.environ, CREDENTIALS_ENV: str(wrong)},
                       capture_output=True, text=True, timeout=EXIT_S)
    last = r.stderr.strip().splitlines()[-1]
    assert r.returncode == 1, r.stderr[-2000:]
    assert last.startswith(f"radseek {role}: the zenoh router at {endpoint} refused user '{role}@uav0'"), last
    assert "Traceback" not in r.stderr and "not-the-secret" not in r.stderr + r.stdout, r.stderr[-2000:]


@pytest.mark.io
def test_a_refused_session_of_a_zenoh_config_file_names_its_user(auth_router, tmp_path):
    """A board given its own client config (docs/topics.md "Authentication") with a wrong password."""
    endpoint, _ = auth_router
    config = tmp_path / "board.json5"
    config.write_text(json.dumps({"mode": "client", "connect": {"endpoints": [endpoint]},
                                  "transport": {"auth": {"usrpwd": {"user": "detector@uav0",
                                                                    "password": "not-the-secret"}}}}))
    r = subprocess.run([sys.executable, "-m", "radseek_cli", "detector", "--zenoh-config", str(config)],
                       capture_output=True, text=True, timeout=EXIT_S)
    assert r.returncode == 1, r.stderr[-2000:]
    assert r.stderr.strip().splitlines()[-1].startswith(
        f"radseek detector: the zenoh router at {endpoint} refused user 'detector@uav0' of {config}"), r.stderr


@pytest.mark.io
@pytest.mark.slow
@pytest.mark.parametrize("role", ["vehicle", "detector"])
def test_a_run_whose_process_is_refused_ends_naming_it(tmp_path, role):
    """`radseek run` with one process given a wrong password (its own client config, through --ROLE-arg)."""
    out = tmp_path / "run"
    zenoh_port = free_port()
    endpoint = f"tcp/127.0.0.1:{zenoh_port}"
    config = tmp_path / f"{role}.json5"
    config.write_text(json.dumps({"mode": "client", "connect": {"endpoints": [endpoint]},
                                  "transport": {"auth": {"usrpwd": {"user": f"{role}@uav0",
                                                                    "password": "not-the-secret"}}}}))
    cmd = [sys.executable, "-m", "radseek_cli", "run", "--out", str(out), "--quiet", "--no-mcap",
           "--zenoh-port", str(zenoh_port), "--mavlink-port", str(free_udp_port()),
           "--gcs-port", str(free_udp_port()), "--vehicle-local-ports", f"{free_udp_port()},{free_udp_port()}",
           "--timeout", "600", f"--{role}-arg=--zenoh-config={config}"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    last = r.stderr.strip().splitlines()[-1]
    log = out / "logs" / f"{role}.log"
    assert r.returncode == 1, r.stderr[-3000:]
    assert last == (f"radseek run: {role} exited with 1: radseek {role}: the zenoh router at {endpoint} refused "
                    f"user '{role}@uav0' of {config} (wrong password, or that router has other credentials)"
                    f"{': stopped (a vehicle its stack cannot hear must not fly on)' if role == 'vehicle' else ''}"
                    f"; see {log}"), last
    assert "abandoned" not in r.stderr and "Traceback" not in log.read_text()
    # what was recorded is kept: the run's scenario and every process's log; no summary of a flight not flown
    assert (out / "scenario.json").is_file() and (out / "logs" / "router.log").is_file()
    assert not (out / "summary.json").exists()
    if role == "vehicle":  # the mission was up, recording, when the vehicle was refused
        assert (out / "dataset").is_dir() and (out / "logs" / "mission.log").is_file()


@pytest.mark.parametrize(("endpoint", "address"), [
    ("tcp/127.0.0.1:7447", ("127.0.0.1", 7447)), ("tcp/[::1]:7448", ("::1", 7448)), ("udp/127.0.0.1:7447", None),
    ("tcp/127.0.0.1:port", None), ("127.0.0.1:7447", None), ("tcp/127.0.0.1", None)])
def test_the_router_and_its_clients_read_an_endpoint_alike(endpoint, address):
    """One parser for the router's 'is my port taken' and a client's 'does a router answer there'."""
    from radseek.zenoh_session import tcp_address

    assert tcp_address(endpoint) == address
