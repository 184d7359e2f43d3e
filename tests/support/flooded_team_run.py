"""Issue 34's flood and forgery probe on a whole team run, flown once per test run: `radseek run --vehicles 2`
(default scene, seed 3, 50x, every process real) while a local process floods and forges the stack's keys (junk and
forged histograms, sim clocks of 1e9 and -5 s, a forged team estimate, mission/lockstep), once without credentials
and once with the run's observer credentials (a reader's). A team run costs ~25 s of CPU (nine processes), and two
tests flew one each: tests/test_team_flood.py holds that the flooded run keeps its result and its flight,
tests/test_one_world.py that a team's flight through the stack is the in-process team's (launch.offline_team),
frame for frame; lockstep makes the flight independent of timing, and of the flood (test_team_flood)."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time

import pytest

from radseek import topics
from radseek.zenoh_session import RouterRefused, open_session
from tests.conftest import free_port
from tests.support.once_per_run import once_per_run
from tests.support.run_credentials import wait_for_credentials
from tests.test_team_run import free_udp_block

RUN_TIMEOUT_S = 900
SCENE = "default"
SEED = 3


def _forgeries() -> list[tuple[str, bytes]]:
    """(key, payload) pairs a hostile process puts, valid-looking and junk, on every vehicle."""
    k = topics.key
    out = [(k(topics.ESTIMATE, topics.TEAM), json.dumps({"t": 1.0, "sources": [{"x": 0, "y": 0}]}).encode())]
    for v in ("uav0", "uav1"):
        forged = topics.Histogram(seq=1, board_time=1.0, t=1.0, duration=0.1, counts=[65535] * 32, flags=0)
        out += [(k(topics.HISTOGRAM, v), forged.to_bytes()), (k(topics.HISTOGRAM, v), b"\x00junk" * 40),
                (k(topics.SIM_CLOCK, v), json.dumps({"t": 1e9}).encode()),
                (k(topics.SIM_CLOCK, v), json.dumps({"t": -5.0}).encode()),
                (k(topics.MISSION_LOCKSTEP, v), json.dumps({"t": 1e9}).encode())]
    return out


def _flood(session, stop: threading.Event, counter: list[int]) -> None:
    forgeries = _forgeries()
    pubs = [(session.declare_publisher(key), payload) for key, payload in forgeries]
    while not stop.is_set():
        for pub, payload in pubs:
            pub.put(payload)
            counter[0] += 1
        time.sleep(0.002)


def flooded_team_run(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The run: ``out`` (its --out), ``code``, ``stderr``, ``refused`` (an outsider's session was refused) and
    ``sent`` (the flood's puts)."""

    def fly(folder) -> dict:
        out = folder / "run"
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        cmd = [sys.executable, "-m", "radseek_cli", "run", SCENE, "--vehicles", "2", "--out", str(out), "--quiet",
               "--speedup", "50", "--seed", str(SEED), "--no-mcap", "--timeout", str(RUN_TIMEOUT_S),
               "--zenoh-port", endpoint.rsplit(":", 1)[1], "--mavlink-port", str(free_udp_block(2)),
               "--gcs-port", str(free_udp_block(2)),
               "--vehicle-local-ports", f"{free_udp_block(2)},{free_udp_block(2)}"]
        run = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        stop, sent = threading.Event(), [0]
        floods: list[threading.Thread] = []
        session, refused, stderr = None, False, ""
        try:
            users = wait_for_credentials(out, run)
            try:  # an outsider cannot speak at all
                open_session(connect=endpoint, user=None, wait_for_router_s=120).close()
            except RouterRefused:
                refused = True
            observer = next(u for u in users if u.name == "observer")
            session = open_session(connect=endpoint, user=observer, wait_for_router_s=120)
            floods = [threading.Thread(target=_flood, args=(session, stop, sent), daemon=True) for _ in range(2)]
            for t in floods:
                t.start()
            _, stderr = run.communicate(timeout=RUN_TIMEOUT_S + 60)
        finally:
            stop.set()
            for t in floods:
                t.join(10)
            if session is not None:
                session.close()
            if run.poll() is None:
                run.kill()
                run.wait()
        return {"out": out, "code": run.returncode, "stderr": stderr, "refused": refused, "sent": sent[0]}

    return once_per_run(tmp_path_factory, "flooded-team-run", fly)
