"""flight.mcap for Foxglove: the well-known schemas are the Foxglove SDK's, every MAVLink message's schema is
pymavlink's definition of it, the Foxglove messages derived from radseek payloads are right (analytic cases)
and valid, and the log's times are simulation time. The check on a real recorded flight is in
tests/test_run_mcap.py (one flight, checked from every side)."""

import json
import math
import socket
import time

import jsonschema
import numpy as np
import pytest

from radseek import topics
from radseek.board_wire import Frame, encode_frame
from radseek.coordinates import Home, geodetic_to_enu
from radseek.dataset import Scenario, Wall
from radseek.zenoh_session import open_session
from radseek_io import foxglove_schemas
from radseek_io.foxglove_view import FoxgloveView, estimate_entity
from radseek_io.mavlink_json import dialect, mavlink_schema, message_dict
from radseek_io.mcap_log import Recorder, SimTimeline, read
from vehicle_sim.harness import free_udp_port


def _valid(schema_name: str, msg: dict) -> None:
    name = schema_name.split(".", 1)[1]
    jsonschema.Draft202012Validator(foxglove_schemas.schema(name)).validate(msg)


def test_the_foxglove_schemas_are_generated_from_the_sdks_definitions():
    """foxglove_schemas.json is what the installed Foxglove SDK's message definitions give (regenerate with
    python -m radseek_io.foxglove_schemas), and each is a valid JSON schema naming the foxglove message."""
    committed = json.loads(foxglove_schemas.FILE.read_text())["schemas"]
    assert committed == foxglove_schemas.from_sdk()
    for name in foxglove_schemas.NAMES:
        s = foxglove_schemas.schema(name)
        jsonschema.Draft202012Validator.check_schema(s)
        assert s["title"] == f"foxglove.{name}"
    fix = foxglove_schemas.schema("LocationFix")
    assert {"latitude", "longitude", "altitude", "position_covariance", "timestamp"} <= set(fix["required"])
    assert fix["properties"]["timestamp"]["properties"].keys() == {"sec", "nsec"}  # Foxglove's JSON time
    assert [c["const"] for c in fix["properties"]["position_covariance_type"]["oneOf"]] == [0, 1, 2, 3]


def _zero_message(cls):
    """A message of class ``cls`` with every field zero (arrays full, strings filled)."""
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
    args = []
    for name, ctype in zip(cls.fieldnames, cls.fieldtypes, strict=True):
        n = lengths[name]
        if ctype == "char":
            args.append(b"x" * max(n, 1))
        elif n:
            args.append([0] * n)
        else:
            args.append(0)
    return cls(*args)


def test_every_mavlink_message_validates_against_its_generated_schema():
    """Every message of the common dialect, packed as MAVLink 2 and parsed back as the recorder parses it,
    validates against its schema; the schema lists the message's real fields with their types."""
    M = dialect()
    tx, rx = M.MAVLink(None, srcSystem=1), M.MAVLink(None)
    for cls in {c.msgname: c for c in M.mavlink_map.values()}.values():
        (parsed,) = rx.parse_buffer(_zero_message(cls).pack(tx))
        jsonschema.Draft202012Validator(mavlink_schema(cls.msgname)).validate(message_dict(parsed))
    gpi = mavlink_schema("GLOBAL_POSITION_INT")
    assert set(gpi["properties"]) == {"mavpackettype", "time_boot_ms", "lat", "lon", "alt", "relative_alt",
                                      "vx", "vy", "vz", "hdg"}
    assert gpi["properties"]["lat"]["type"] == "integer" and gpi["properties"]["lat"]["minimum"] == -(2**31)
    assert "unit degE7" in gpi["properties"]["lat"]["description"]
    bat = mavlink_schema("BATTERY_STATUS")["properties"]
    assert bat["voltages"]["maxItems"] == 10 and bat["temperature"]["type"] == "integer"
    assert mavlink_schema("STATUSTEXT")["properties"]["text"] == {"type": "string", "maxLength": 50,
                                                                  "description": "char[50]"}
    assert mavlink_schema("ATTITUDE")["properties"]["roll"]["type"] == "number"  # a NaN roll is left out


def test_a_nan_mavlink_float_is_left_out_and_a_nan_element_is_null():
    """MAVLink's "unknown" is NaN, which JSON has not: a NaN field is left out of the message (its schema does not
    require it), a NaN element of a float array is null (its position allows it); the message is strict JSON."""
    M = dialect()
    tx, rx = M.MAVLink(None, srcSystem=1), M.MAVLink(None)
    cov = [math.nan] + [0.0] * 20  # ODOMETRY's "covariance unknown"
    odo = M.MAVLink_odometry_message(5, 1, 12, 1.0, 2.0, math.nan, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0.0, 0.0,
                                     0.0, [0.0] * 21, cov, 0, 3, 98)
    (parsed,) = rx.parse_buffer(odo.pack(tx))
    d = message_dict(parsed)
    assert "z" not in d and d["x"] == 1.0 and d["velocity_covariance"][0] is None
    json.loads(json.dumps(d), parse_constant=lambda c: pytest.fail(f"{c} in the JSON"))
    schema = mavlink_schema("ODOMETRY")
    jsonschema.Draft202012Validator(schema).validate(d)
    assert "z" not in schema["required"] and {"time_usec", "q", "quality"} <= set(schema["required"])  # arrays, ints
    with pytest.raises(jsonschema.ValidationError):  # a null scalar is not a number: left out, never null
        jsonschema.Draft202012Validator(schema).validate({**d, "z": None})


def test_log_time_is_sim_time_monotonic_per_channel():
    tl = SimTimeline()
    assert tl.stamp("a", None) == (0, 0)  # nothing seen yet: time 0
    assert tl.stamp("a", 2_000) == (2_000, 2_000)
    assert tl.stamp("b", None) == (2_000, 2_000)  # unstamped: the latest sim time seen
    assert tl.stamp("a", 1_000) == (2_000, 1_000)  # late on its channel: log time held, publish time its own
    assert tl.stamp("b", 1_500) == (2_000, 1_500)
    assert tl.stamp("c", 1_500) == (1_500, 1_500)  # another channel may be earlier than the latest
    assert tl.stamp("c", 10**30) == (2_000, 2_000)  # not a simulation time (e.g. a Unix time): unstamped


def test_a_pose_becomes_pose_transform_and_a_location_through_the_home():
    home = Home(47.0, 8.0, 400.0)
    view = FoxgloveView(home=home)
    pose = topics.Pose(t=3.5, x=30.0, y=-40.0, z=2.0, yaw=math.pi / 2, var_x=0.04, var_y=0.09, var_z=0.01)
    out = {ch: (schema, msg) for ch, schema, msg in view.derive(topics.key(topics.POSE), json.loads(pose.to_bytes()),
                                                                  3_500_000_000)}
    assert set(out) == {"foxglove/uav0/pose", "foxglove/uav0/tf", "foxglove/uav0/location"}
    for schema, msg in out.values():
        _valid(schema, msg)
        assert msg["timestamp"] == {"sec": 3, "nsec": 500_000_000}
    fix = out["foxglove/uav0/location"][1]
    np.testing.assert_allclose(geodetic_to_enu(home, fix["latitude"], fix["longitude"], fix["altitude"]),
                               [30.0, -40.0, 2.0], atol=1e-6)
    assert fix["position_covariance"][::4] == [0.04, 0.09, 0.01] and fix["position_covariance_type"] == 2
    assert fix["heading"] == pytest.approx(0.0, abs=1e-12)  # ENU yaw +90 deg (north) is heading 0
    tf = out["foxglove/uav0/tf"][1]
    assert (tf["parent_frame_id"], tf["child_frame_id"]) == ("map", "uav0")
    assert tf["rotation"]["z"] == pytest.approx(math.sqrt(0.5)) and tf["translation"]["x"] == 30.0
    # a vehicle whose MAVLink is recorded takes its fix from GLOBAL_POSITION_INT instead
    gps_view = FoxgloveView(home=home, gps_vehicles=frozenset({"uav0"}))
    assert "foxglove/uav0/location" not in {c for c, *_ in gps_view.derive(topics.key(topics.POSE),
                                                                          json.loads(pose.to_bytes()), 1)}
    gpi = {"mavpackettype": "GLOBAL_POSITION_INT", "time_boot_ms": 3500, "lat": 473977420, "lon": 85455940,
           "alt": 490000, "relative_alt": 2000, "vx": 100, "vy": -200, "vz": 50, "hdg": 9000}
    ((ch, schema, fix),) = gps_view.derive("mavlink/GLOBAL_POSITION_INT", gpi, 3_500_000_000)
    _valid(schema, fix)
    assert ch == "foxglove/uav0/location" and (fix["latitude"], fix["longitude"], fix["altitude"]) == (
        47.397742, 8.545594, 490.0)
    assert fix["velocity"] == {"x": -2.0, "y": 1.0, "z": -0.5} and fix["heading"] == pytest.approx(math.pi / 2)


def test_the_estimate_ellipse_is_its_covariance():
    """A source with x-y covariance [[4, 1.5], [1.5, 1]]: every point of the 1-sigma line is at Mahalanobis
    distance 1, and of the 95 % line at sqrt(5.991); the 1-sigma ellipse's x extent is sqrt(C_xx) = 2."""
    cov = np.zeros((4, 4))
    cov[:2, :2] = [[4.0, 1.5], [1.5, 1.0]]
    est = topics.Estimate(t=1.0, method="mle", sources=[{"x": 5.0, "y": 6.0, "z": 0.5, "cps_at_1m": 100.0}],
                          background_cps=1.0, covariance=cov.ravel().tolist())
    ent = estimate_entity(json.loads(est.to_bytes()), 1)
    one, ninety_five = ent["lines"]
    inv = np.linalg.inv(cov[:2, :2])
    for line, r in ((one, 1.0), (ninety_five, math.sqrt(5.991))):
        d = np.array([[p["x"] - 5.0, p["y"] - 6.0] for p in line["points"]])
        np.testing.assert_allclose(np.sqrt(np.einsum("ij,jk,ik->i", d, inv, d)), r, rtol=1e-9)
        assert all(p["z"] == 0.5 for p in line["points"])
    xs = [p["x"] - 5.0 for p in one["points"]]
    assert max(xs) == pytest.approx(2.0, rel=0.01)  # sampled at 48 points: the extreme within 1 %
    assert ent["spheres"][0]["pose"]["position"] == {"x": 5.0, "y": 6.0, "z": 0.5}
    unknown = topics.Estimate(t=1.0, method="x", sources=[{"x": 1.0, "y": 2.0, "z": 0.0, "cps_at_1m": 9.0}],
                              background_cps=1.0, covariance=[math.nan] * 16)  # a covariance not known
    no_cov = estimate_entity(unknown.to_dict(), 1)
    assert no_cov["lines"] == [] and len(no_cov["spheres"]) == 1
    with pytest.raises(topics.PayloadError):  # not the layout: nothing drawn (FoxgloveView.derive skips it)
        estimate_entity({"t": 1.0, "sources": [{"x": 1, "y": 2, "z": 0}], "covariance": []}, 1)


@pytest.mark.io
def test_recorder_writes_walls_decoded_frames_and_mavlink_in_sim_time(router, tmp_path):
    """A sim clock and a raw frame over a live router and a GLOBAL_POSITION_INT datagram on the GCS port:
    the walls of the scenario are on foxglove/map, the raw frame is decoded beside it at the latest sim
    time, MAVLink is logged at its time_boot_ms, and every JSON message validates against its channel's
    schema."""
    M = dialect()
    edges = np.linspace(30.0, 3000.0, topics.N_CHANNELS + 1)
    scenario = Scenario(channel_edges_keV=edges, background_cps=5.0, source_z=0.0, bounds_min=np.zeros(3),
                        bounds_max=np.array([20.0, 10.0, 5.0]), walls=(Wall((2.0, 0.0), (2.0, 8.0), 0.3, 3.0),))
    port = free_udp_port()
    session = open_session(None, router)
    rec = Recorder(tmp_path / "f.mcap", session, mavlink_port=port, scenario=scenario)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    raw = encode_frame(Frame(seq=7, board_time_us=1_200_000, integration_us=100_000, flags=0,
                             counts=tuple(range(topics.N_CHANNELS))))
    want = {topics.key(topics.SIM_CLOCK), topics.key(topics.RAW_FRAME), "mavlink/GLOBAL_POSITION_INT"}
    try:
        deadline = time.monotonic() + 30  # the subscription reaches the router in milliseconds
        while not want <= set(rec.log._channels):
            assert time.monotonic() < deadline, f"missing {want - set(rec.log._channels)}"
            if topics.key(topics.SIM_CLOCK) not in rec.log._channels:
                session.put(topics.key(topics.SIM_CLOCK), topics.SimClock(t=12.0, speedup=1.0).to_bytes())
                time.sleep(0.1)
                continue
            if topics.key(topics.RAW_FRAME) not in rec.log._channels:
                session.put(topics.key(topics.RAW_FRAME), raw)
            else:
                mav = M.MAVLink(None, srcSystem=1)
                tx.sendto(M.MAVLink_global_position_int_message(12500, 473977420, 85455940, 490000, 2000, 0, 0, 0,
                                                                65535).pack(mav), ("127.0.0.1", port))
            time.sleep(0.1)
    finally:
        tx.close()
        path = rec.stop()
        session.close()
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        msgs = [(s, c, m) for s, c, m in make_reader(f).iter_messages()]
    by = {c.topic: (s, c, m) for s, c, m in msgs}
    for s, c, m in msgs:
        if c.message_encoding == "json":
            assert s.encoding == "jsonschema"
            jsonschema.Draft202012Validator(json.loads(s.data)).validate(json.loads(m.data))
    s, _, m = by["foxglove/map"]
    walls = next(e for e in json.loads(m.data)["entities"] if e["id"] == "walls")["cubes"]
    assert s.name == "foxglove.SceneUpdate" and len(walls) == 1
    assert walls[0]["size"] == {"x": 8.0, "y": 0.3, "z": 3.0} and walls[0]["pose"]["position"]["y"] == 4.0
    _, c, m = by[topics.key(topics.RAW_FRAME) + "/decoded"]
    dec = json.loads(m.data)
    assert dec["counts"] == list(range(topics.N_CHANNELS)) and (dec["seq"], dec["duration"]) == (7, 0.1)
    assert dec["t"] == 12.0 and m.log_time == 12_000_000_000  # no sim time of its own: the latest seen
    assert c.message_encoding == "json"
    s, c, m = by[topics.key(topics.RAW_FRAME)]
    assert m.data == raw  # the raw channel is byte for byte, a ROS 1 message (Foxglove decodes it)
    assert (c.message_encoding, s.encoding, s.name) == ("ros1", "ros1msg", topics.RAW_FRAME_SCHEMA)
    _, _, m = by["mavlink/GLOBAL_POSITION_INT"]
    assert m.log_time == m.publish_time == 12_500_000_000  # the last one: several may have been sent
    _, _, m = by["foxglove/uav0/location"]
    assert m.log_time == 12_500_000_000 and "heading" not in json.loads(m.data)  # hdg 65535: unknown
    assert sorted(ch for ch, *_ in read(path)) == sorted(by)
