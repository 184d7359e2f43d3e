"""MCAP logs: a recorder on a live router and the vehicle's GCS port writes every radseek topic (JSON with
schemas from radseek/topics.py, the raw board frame as bytes) and the MAVLink telemetry; the mcap
reader opens the file and finds them all. Real processes and sockets."""

import json
import time

import pytest

from radseek import topics
from radseek.topics import json_schema
from radseek.zenoh_session import open_session
from radseek_io.mcap_log import Recorder, read
from vehicle_sim.harness import VehicleProcess, free_udp_port

WAIT_S = 60.0  # bounds waiting only


def test_json_schema_follows_the_dataclass():
    s = json_schema(topics.Histogram)
    assert s["title"] == "Histogram" and s["properties"]["counts"] == {"type": "array", "items": {"type": "integer"}}
    assert s["properties"]["live_time"] == {"type": "number"} and "live_time" not in s["required"]  # absent if None
    assert s["required"] == ["seq", "board_time", "t", "duration", "counts"]  # the fields without a default


@pytest.mark.slow
def test_recorder_logs_every_topic_and_mavlink(router, tmp_path):
    gcs_port = free_udp_port()
    session = open_session(None, router)
    rec = Recorder(tmp_path / "flight.mcap", session, mavlink_port=gcs_port)
    others = [t for t in (*topics.PAYLOADS, topics.RAW_FRAME)
              if t not in (topics.SIM_CLOCK, topics.SIM_TRUTH_POSE, topics.POSE)]
    want = {topics.key(t) for t in (*topics.PAYLOADS, topics.RAW_FRAME)} | {"mavlink/HEARTBEAT",
                                                                            "mavlink/GLOBAL_POSITION_INT"}
    try:
        with VehicleProcess(free_udp_port(), gcs_port, ["--speedup", "5", "--connect", router], zenoh=True):
            deadline = time.monotonic() + WAIT_S
            while not want <= set(rec.log._channels):  # the vehicle publishes clock/poses; we publish the rest
                assert time.monotonic() < deadline, f"missing {want - set(rec.log._channels)}"
                for t in others:
                    data = bytes(90) if t == topics.RAW_FRAME else json.dumps({"t": 1.0}).encode()
                    session.put(topics.key(t), data)
                time.sleep(0.2)
    finally:
        path = rec.stop()
        session.close()
    messages = list(read(path))
    seen = {ch for ch, *_ in messages}
    assert want <= seen
    pose = next(p for ch, _, _, p in messages if ch == topics.key(topics.POSE))
    assert {"x", "y", "z", "var_x"} <= set(pose)
    raw = next(p for ch, _, _, p in messages if ch == topics.key(topics.RAW_FRAME))
    assert raw == bytes(90)
    hb = next(p for ch, _, _, p in messages if ch == "mavlink/HEARTBEAT")
    assert hb["autopilot"] == 12  # PX4
    clock = [(pub, p["t"]) for ch, _, pub, p in messages if ch == topics.key(topics.SIM_CLOCK)]
    assert all(pub == round(t * 1e9) for pub, t in clock)  # publish_time is the sim time


@pytest.mark.io
def test_a_teams_mavlink_is_recorded_per_vehicle(tmp_path):
    """Datagrams on two named GCS ports land on mavlink/<vehicle>/<MESSAGE>, each vehicle's own."""
    import os
    import socket

    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink.dialects.v20 import common as M

    ports = {"uav0": free_udp_port(), "uav1": free_udp_port()}
    rec = Recorder(tmp_path / "team.mcap", None, mavlink_ports=ports)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for sysid, port in enumerate(ports.values(), start=1):
            mav = M.MAVLink(None, srcSystem=sysid)
            hb = M.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3).pack(mav)
            for _ in range(3):
                tx.sendto(hb, ("127.0.0.1", port))
        deadline = time.monotonic() + 5
        while rec.log.count < 6 and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        tx.close()
        path = rec.stop()
    channels = [ch for ch, *_ in read(path)]
    assert channels.count("mavlink/uav0/HEARTBEAT") == 3 and channels.count("mavlink/uav1/HEARTBEAT") == 3
    assert not any(ch == "mavlink/HEARTBEAT" for ch in channels)
