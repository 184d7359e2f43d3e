"""A flooding publisher cannot get another session's connection closed (issue 34): the router's QoS policy
(``radseek.zenoh_qos``) rewrites every radseek put to congestion control DROP.

A real `radseek router` with the credentials `radseek run` generates; real client sessions as its users. The
detector's user floods its own key with congestion control BLOCK while the observer, subscribed to everything,
sleeps on each flood sample (a subscriber that cannot keep up): its queue in the router fills. Without the
policy the router waits 5 s (zenoh's ``block.wait_before_close``) on the blocked push, logs "Unable to push non
droppable network message ... Closing transport!" and closes the observer's connection, losing what the vehicle
sent it meanwhile. With it, flood samples are dropped and the connection and the vehicle's samples stay.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from launch.zenoh_auth import stack_env, write_run_credentials
from radseek import topics
from radseek.zenoh_auth import read_credentials
from radseek.zenoh_session import open_session
from tests.conftest import free_port

pytestmark = [pytest.mark.io, pytest.mark.slow]

FLOOD_S = 7.0  # longer than zenoh's 5 s wait before it closes a transport it cannot push to
SLOW_S = 0.05  # s the observer spends on each flood sample while the flood lasts
POSE_HZ = 20.0
QUIET_S = 1.5  # s of vehicle samples before and after the flood
WAIT_S = 60.0  # bound on waiting for the observer to catch up (a loaded host is slow), never asserted
CLOSED = ("Closing transport", "Unable to push")


def _start_router(folder: Path) -> tuple[subprocess.Popen, str, Path]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    credentials = write_run_credentials(folder, ["uav0"], endpoint)
    log = folder / "router.log"
    with log.open("w") as fh:
        proc = subprocess.Popen([sys.executable, "-m", "radseek_cli", "router", "--listen", endpoint],
                                env={**os.environ, **stack_env(credentials)}, stdout=fh, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + WAIT_S
    while "listening" not in log.read_text() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    assert "listening" in log.read_text(), log.read_text()
    return proc, endpoint, credentials


class Observer:
    """Subscribed to every radseek key: keeps the vehicle's pose numbers, sleeps on each flood sample while
    ``slow`` is set."""

    def __init__(self, session: zenoh.Session):
        self.poses: set[int] = set()
        self.flood_heard = 0
        self.qos: dict[str, set] = {"pose": set(), "flood": set()}  # (priority, congestion control) seen
        self.slow = threading.Event()
        self.sub = session.declare_subscriber(topics.all_keys("uav0"), self._on)

    def _on(self, sample) -> None:
        pose = str(sample.key_expr).endswith(topics.POSE)
        self.qos["pose" if pose else "flood"].add((str(sample.priority), str(sample.congestion_control)))
        if pose:
            self.poses.add(int(sample.payload.to_bytes()))
            return
        self.flood_heard += 1
        if self.slow.is_set():
            time.sleep(SLOW_S)


def test_a_block_flood_toward_a_slow_subscriber_does_not_close_its_connection(tmp_path):
    router, endpoint, credentials = _start_router(tmp_path)
    users = {u.name: u for u in read_credentials(credentials)}
    sessions = []
    try:
        sessions = [open_session(connect=endpoint, user=users[name], wait_for_router_s=WAIT_S)
                    for name in ("observer", "detector@uav0", "vehicle@uav0")]
        observer_s, detector_s, vehicle_s = sessions
        observer = Observer(observer_s)
        flood_pub = detector_s.declare_publisher(topics.key(topics.HISTOGRAM, "uav0"),
                                                 congestion_control=zenoh.CongestionControl.BLOCK,
                                                 priority=zenoh.Priority.REAL_TIME)  # asks for the first queue
        pose_pub = vehicle_s.declare_publisher(topics.key(topics.POSE, "uav0"))
        time.sleep(0.5)  # declarations reach the router

        flooding = threading.Event()
        flood_sent = [0]

        def flood() -> None:
            payload = b"z" * 1000
            end = time.monotonic() + FLOOD_S
            while time.monotonic() < end:
                flood_pub.put(payload)
                flood_sent[0] += 1

        phases: dict[str, list[int]] = {"before": [], "during": [], "after": []}
        n = 0

        def send_poses(phase: str, until) -> None:
            nonlocal n
            while until():
                pose_pub.put(str(n).encode())
                phases[phase].append(n)
                n += 1
                time.sleep(1.0 / POSE_HZ)

        t = time.monotonic()
        send_poses("before", lambda: time.monotonic() < t + QUIET_S)
        observer.slow.set()
        flooding.set()
        flooder = threading.Thread(target=lambda: (flood(), flooding.clear()), daemon=True)
        flooder.start()
        send_poses("during", flooding.is_set)
        flooder.join(WAIT_S)
        observer.slow.clear()
        t = time.monotonic()
        send_poses("after", lambda: time.monotonic() < t + QUIET_S)
        sent = [i for p in phases.values() for i in p]
        deadline = time.monotonic() + WAIT_S
        while not observer.poses.issuperset(sent) and time.monotonic() < deadline:
            time.sleep(0.2)
        time.sleep(1.0)  # the router's log is written asynchronously
    finally:
        for s in sessions:
            s.close()
        router.terminate()
        router.wait(60)
    log = (tmp_path / "router.log").read_text()
    missing = {p: len(set(ids) - observer.poses) for p, ids in phases.items()}
    print(f"flood sent {flood_sent[0]} heard {observer.flood_heard}; poses sent "
          f"{ {p: len(ids) for p, ids in phases.items()} } missing {missing}")
    assert observer.flood_heard < flood_sent[0], "no overload: the test did not fill the router's queue"
    assert not [line for line in log.splitlines() if any(c in line for c in CLOSED)], log[-2000:]
    assert missing == {"before": 0, "during": 0, "after": 0}
    drop = str(zenoh.CongestionControl.DROP)  # whatever the publishers asked: the vehicle's queue first, then the rest
    assert observer.qos == {"pose": {(str(zenoh.Priority.DATA_HIGH), drop)},
                            "flood": {(str(zenoh.Priority.DATA), drop)}}
