"""The vehicle's mission protocol state machine: upload / download / clear, retransmission and
timeouts, and the MAV_MISSION_RESULT of each refusal (including the geofence)."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as M

from radseek.coordinates import enu_to_geodetic
from vehicle_sim.geofence import Geofence
from vehicle_sim.harness import item, thread_config
from vehicle_sim.mission_protocol import MissionProtocol
from vehicle_sim.vehicle import Vehicle

GCS = (255, 190)


def from_gcs(msg, src=GCS):
    """Give a constructed message the header a received one has."""
    buf = msg.pack(M.MAVLink(None, srcSystem=src[0], srcComponent=src[1]))
    return M.MAVLink(None).parse_buffer(buf)[0]


def types(replies):
    return [(m.get_type(), getattr(m, "seq", getattr(m, "type", None))) for m in replies]


def wp(seq, alt=5.0, hold=0.0, lat=47.3978, lon=8.5457, cmd=M.MAV_CMD_NAV_WAYPOINT, frame=6):
    return from_gcs(item(seq, cmd, lat, lon, alt, hold, frame=frame))


def count(n, mission_type=0):
    return from_gcs(M.MAVLink_mission_count_message(1, 1, n, mission_type))


def test_upload_then_download_round_trip():
    p = MissionProtocol()
    assert types(p.handle(count(3), 0.0)) == [("MISSION_REQUEST_INT", 0)]
    assert types(p.handle(wp(0), 0.1)) == [("MISSION_REQUEST_INT", 1)]
    assert types(p.handle(wp(1, hold=30), 0.2)) == [("MISSION_REQUEST_INT", 2)]
    # the final ACK goes out once (MAVSDK takes any ACCEPTED as the end of its current upload, whatever its
    # mission type: a second copy arriving late breaks the next upload)
    assert types(p.handle(wp(2, cmd=M.MAV_CMD_NAV_LAND), 0.3)) == [("MISSION_ACK", M.MAV_MISSION_ACCEPTED)]
    assert p.changed and len(p.items) == 3 and p.items[1].param1 == 30
    (c,) = p.handle(from_gcs(M.MAVLink_mission_request_list_message(1, 1, 0)), 1.0)
    assert c.get_type() == "MISSION_COUNT" and c.count == 3
    (it,) = p.handle(from_gcs(M.MAVLink_mission_request_int_message(1, 1, 1, 0)), 1.1)
    assert it.get_type() == "MISSION_ITEM_INT" and it.seq == 1 and it.param1 == 30 and it.x == 473978000
    (fl,) = p.handle(from_gcs(M.MAVLink_mission_request_message(1, 1, 1, 0)), 1.1)
    assert fl.get_type() == "MISSION_ITEM" and fl.x == pytest.approx(47.3978)
    (bad,) = p.handle(from_gcs(M.MAVLink_mission_request_int_message(1, 1, 9, 0)), 1.2)
    assert bad.type == M.MAV_MISSION_INVALID_SEQUENCE


def test_lost_request_is_retransmitted_then_upload_cancelled():
    p = MissionProtocol(retry_s=0.5, max_retries=2)
    p.handle(count(2), 0.0)
    assert p.poll(0.3) == []
    assert types(p.poll(0.6)) == [("MISSION_REQUEST_INT", 0)]
    assert types(p.poll(1.2)) == [("MISSION_REQUEST_INT", 0)]
    assert types(p.poll(1.8)) == [("MISSION_ACK", M.MAV_MISSION_OPERATION_CANCELLED)]
    assert not p.uploading and p.items == []


def test_out_of_order_and_duplicate_items_are_answered_by_the_protocol():
    p = MissionProtocol()
    p.handle(count(3), 0.0)
    assert types(p.handle(wp(2), 0.1)) == [("MISSION_REQUEST_INT", 0)]  # skipped ahead: ask again
    p.handle(wp(0), 0.2)
    assert p.handle(wp(0), 0.3) == []  # duplicate: ignored
    assert types(p.handle(count(3), 0.4)) == [("MISSION_REQUEST_INT", 0)]  # repeated count restarts
    for k in range(3):
        replies = p.handle(wp(k), 0.5)
    assert types(replies) == [("MISSION_ACK", 0)]
    assert types(p.handle(wp(2), 0.6)) == [("MISSION_ACK", 0)]  # our ACK was lost: re-acknowledged
    assert p.handle(wp(1), 0.7) == []  # stray item outside an upload: ignored


@pytest.mark.parametrize("msg, result", [
    (wp(0, cmd=M.MAV_CMD_DO_JUMP), M.MAV_MISSION_UNSUPPORTED),
    (wp(0, frame=M.MAV_FRAME_LOCAL_NED), M.MAV_MISSION_UNSUPPORTED_FRAME),
    (wp(0, hold=-1), M.MAV_MISSION_INVALID_PARAM1),
    (wp(0, hold=math.nan), M.MAV_MISSION_INVALID_PARAM1),
    (wp(0, alt=math.nan), M.MAV_MISSION_INVALID_PARAM7),
])
def test_bad_items_refused_with_their_result(msg, result):
    p = MissionProtocol()
    p.handle(count(2), 0.0)
    assert types(p.handle(msg, 0.1)) == [("MISSION_ACK", result)]
    assert p.items == [] and not p.uploading


def test_count_limits_types_and_clear():
    p = MissionProtocol(max_items=10)
    assert types(p.handle(count(11), 0)) == [("MISSION_ACK", M.MAV_MISSION_NO_SPACE)]
    # fence (1) and rally (2) lists are transferred like the mission; an unknown type is unsupported
    assert types(p.handle(count(2, mission_type=1), 0)) == [("MISSION_REQUEST_INT", 0)]
    assert types(p.handle(count(2, mission_type=7), 0)) == [("MISSION_ACK", M.MAV_MISSION_UNSUPPORTED)]
    p.handle(count(0, mission_type=1), 0)
    (c,) = p.handle(from_gcs(M.MAVLink_mission_request_list_message(1, 1, 2)), 0)
    assert c.count == 0  # no rally points stored yet
    p.handle(count(1), 0)
    p.handle(wp(0), 0)
    assert len(p.items) == 1
    p.changed = False
    assert types(p.handle(from_gcs(M.MAVLink_mission_clear_all_message(1, 1, 0)), 0)) == [("MISSION_ACK", 0)]
    assert p.items == [] and p.changed
    # a second GCS is refused while the first one uploads
    p.handle(count(2), 0)
    (ack,) = p.handle(from_gcs(M.MAVLink_mission_count_message(1, 1, 2, 0), src=(254, 1)), 0)
    assert ack.type == M.MAV_MISSION_DENIED


@pytest.mark.io
def test_geofence_rejects_items_outside_bounds_per_axis():
    v = Vehicle(thread_config(0, 0, fence=Geofence(-50, -50, 0, 50, 50, 30)))
    try:
        home = v.home

        def at(x, y, z, **kw):
            lat, lon, _ = enu_to_geodetic(home, (x, y, z))
            return wp(0, alt=z, lat=lat, lon=lon, **kw)

        p = v.protocol
        # param5 (x) is the latitude, i.e. north (ENU y); param6 (y) the longitude, i.e. east (ENU x)
        cases = [(at(10, 10, 5), M.MAV_MISSION_ACCEPTED), (at(80, 0, 5), M.MAV_MISSION_INVALID_PARAM6_Y),
                 (at(0, -70, 5), M.MAV_MISSION_INVALID_PARAM5_X), (at(0, 0, 45), M.MAV_MISSION_INVALID_PARAM7),
                 (wp(0, lat=91.0, lon=0.0), M.MAV_MISSION_INVALID_PARAM5_X)]
        for msg, result in cases:
            p.handle(count(1), 0)
            assert types(p.handle(msg, 0))[0] == ("MISSION_ACK", result)
    finally:
        v.link.close()


def _random_msg(kind, seq, count, value, mtype):
    if kind == 0:
        return count_msg(count, mtype)
    if kind == 1:
        x = (seq * 7919 + count) % 2**32 - 2**31  # any int32 lat/lon, most of them invalid
        return from_gcs(M.MAVLink_mission_item_int_message(1, 1, seq % 8, count % 12, count % 400 if seq % 2 else 16,
                                                           0, 1, value, value, value, value, x, -x - 1, value, mtype))
    if kind == 2:
        return from_gcs(M.MAVLink_mission_request_int_message(1, 1, seq, mtype))
    if kind == 3:
        return from_gcs(M.MAVLink_mission_request_list_message(1, 1, mtype))
    if kind == 4:
        return from_gcs(M.MAVLink_mission_ack_message(1, 1, count % 16, mtype))
    return from_gcs(M.MAVLink_mission_clear_all_message(1, 1, mtype))


def count_msg(n, mission_type=0):
    return from_gcs(M.MAVLink_mission_count_message(1, 1, n, mission_type))


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 5), st.integers(0, 65535), st.integers(0, 12),
                          st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32),
                                    st.integers(-(2**31), 2**31 - 1).map(float)),
                          st.sampled_from([0, 1, 2, 255])), max_size=40),
       st.floats(0, 100))
def test_any_message_sequence_is_answered_never_raises(msgs, t):
    """Bad input is answered by the protocol (ACK with a result code) or ignored, never an exception."""
    p = MissionProtocol()
    for k, (kind, seq, n, value, mtype) in enumerate(msgs):
        for reply in p.handle(_random_msg(kind, seq, n, value, mtype), t + k * 0.1) + p.poll(t + k * 0.1):
            assert reply.get_type() in {"MISSION_ACK", "MISSION_REQUEST_INT", "MISSION_COUNT", "MISSION_ITEM_INT"}
    assert all(isinstance(i.seq, int) for i in p.items) and [i.seq for i in p.items] == list(range(len(p.items)))
