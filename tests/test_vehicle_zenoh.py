"""The vehicle's zenoh side: it keeps answering MAVLink with no router up, connects when one appears,
and then publishes the clock, the TRUE pose (sim/truth_pose) and the drifting ESTIMATED pose with its
variance (pose) on the shared sim clock."""

import math
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as M

from radseek import topics
from radseek.zenoh_session import open_session
from vehicle_sim.harness import Gcs, VehicleProcess, free_udp_port

pytestmark = pytest.mark.slow


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_vehicle_publishes_truth_and_estimate_and_never_waits_for_zenoh():
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    gcs_port = free_udp_port()
    args = ["--speedup", "20", "--connect", endpoint, "--vehicle-name", "uavz", "--drift", "0.2"]
    with VehicleProcess(free_udp_port(), gcs_port, args, zenoh=True), Gcs(gcs_port) as gcs:
        gcs.recv("HEARTBEAT")  # no router yet: MAVLink is up regardless
        assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
        router = subprocess.Popen([sys.executable, "-m", "radseek_cli", "router", "--listen", endpoint],
                                  stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            assert "listening" in router.stdout.readline()
            got: dict[str, list] = {topics.SIM_CLOCK: [], topics.SIM_TRUTH_POSE: [], topics.POSE: []}
            lock = threading.Lock()

            def on_sample(sample):
                topic = topics.topic_of(str(sample.key_expr))
                cls = topics.PAYLOADS[topic]
                with lock:
                    got[topic].append(cls.from_bytes(sample.payload.to_bytes()))

            with open_session(connect=endpoint) as session:
                sub = session.declare_subscriber(topics.all_keys("uavz"), on_sample)
                deadline = time.monotonic() + 60  # bounds the wait only
                while not all(got.values()) and time.monotonic() < deadline:
                    time.sleep(0.05)
                assert all(got.values()), {k: len(v) for k, v in got.items()}
                assert gcs.command(M.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 7) == M.MAV_RESULT_ACCEPTED
                gcs.recv("EXTENDED_SYS_STATE", lambda m: m.landed_state == M.MAV_LANDED_STATE_IN_AIR)
                lat = 47.397742 + 30 / 111195.0  # ~30 m north
                assert gcs.command(M.MAV_CMD_DO_REPOSITION, -1, 0, 0, math.nan, lat, 8.545594,
                                   490.5) == M.MAV_RESULT_ACCEPTED
                gcs.recv("LOCAL_POSITION_NED", lambda m: abs(m.x - 30) < 0.3 and abs(m.vx) < 0.1)
                # the estimated pose of the arrival reaches zenoh too (an event, not a fixed sleep)
                deadline = time.monotonic() + 60
                while time.monotonic() < deadline:
                    with lock:
                        if abs(got[topics.POSE][-1].y - 30.0) < 0.3:
                            break
                    time.sleep(0.05)
                sub.undeclare()
        finally:
            router.terminate()
            try:  # a wait bound only: shutting the router down is not what this test checks
                router.wait(60)
            except subprocess.TimeoutExpired:
                router.kill()
                router.wait()
    with lock:
        clocks, truths, poses = got[topics.SIM_CLOCK], got[topics.SIM_TRUTH_POSE], got[topics.POSE]
    assert clocks[0].speedup == 20.0 and all(b.t >= a.t for a, b in zip(clocks, clocks[1:], strict=False))
    last_t, last_e = truths[-1], poses[-1]
    # the estimate is where the vehicle believes it is (30 m north of home, 2.5 m up) ...
    assert last_e.y == pytest.approx(30.0, abs=0.3) and last_e.z == pytest.approx(2.5, abs=0.3)
    assert last_e.yaw == pytest.approx(math.pi / 2, abs=0.05)  # ENU: facing north
    # ... the truth differs by the odometry drift, whose reported variance grew with the ~32 m flown
    err = np.hypot(last_t.x - last_e.x, last_t.y - last_e.y)
    assert 0 < err < 6 * math.sqrt(last_e.var_x + last_e.var_y)
    assert last_e.var_x > poses[0].var_x and last_e.var_x == pytest.approx(1e-4 + 0.04 * 32.5, rel=0.1)
