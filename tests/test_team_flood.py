"""Issue 34's flood and forgery probe on a whole team run: while `radseek run --vehicles 2` flies, a local process
floods and forges the stack's keys (junk and forged histograms, sim clocks of 1e9 and -5 s, a forged team estimate,
mission/lockstep), once without credentials and once with the run's observer credentials (a reader's). The run
keeps its result: summary.json with both vehicles' results, and the very flight an unflooded team flies (the
in-process team of `launch.offline_team`, frame for frame: lockstep makes the flight independent of timing).
"""

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
from tests.support.run_credentials import wait_for_credentials
from tests.support.team_frames import assert_same_team_flight
from tests.test_team_run import free_udp_block

RUN_TIMEOUT_S = 900
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


@pytest.mark.slow
@pytest.mark.io
@pytest.mark.timeout(RUN_TIMEOUT_S + 300)
def test_a_flooded_and_forged_team_run_keeps_its_result_and_its_flight(tmp_path):

    out = tmp_path / "run"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cmd = [sys.executable, "-m", "radseek_cli", "run", "--vehicles", "2", "--out", str(out), "--quiet",
           "--speedup", "50", "--seed", str(SEED), "--no-mcap", "--timeout", str(RUN_TIMEOUT_S),
           "--zenoh-port", endpoint.rsplit(":", 1)[1], "--mavlink-port", str(free_udp_block(2)),
           "--gcs-port", str(free_udp_block(2)), "--vehicle-local-ports", f"{free_udp_block(2)},{free_udp_block(2)}"]
    run = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stop, sent = threading.Event(), [0]
    floods: list[threading.Thread] = []
    session = None
    try:
        users = wait_for_credentials(out, run)
        with pytest.raises(RouterRefused):  # an outsider cannot speak at all
            open_session(connect=endpoint, user=None, wait_for_router_s=120)
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
    assert run.returncode in (0, 3), stderr[-3000:]  # 3: searched to the end of the dwell budget; 4 would be a loss
    assert sent[0] > 1000, sent  # the flood went on while the team flew
    summary = json.loads((out / "summary.json").read_text())
    rows = {r["vehicle"]: r for r in summary["per_vehicle"]}
    assert set(rows) == {"uav0", "uav1"} and not any(r["failed"] for r in rows.values()), rows
    for name in rows:
        log = (out / "logs" / f"mission-{name}.log").read_text()
        assert "Traceback" not in log, log[-3000:]
    # the flight an unflooded team flies, frame for frame
    assert_same_team_flight(out, summary, "default", SEED)
