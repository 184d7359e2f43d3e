"""Issue 12 probes of the vehicle's MAVLink handling, over real UDP on loopback with a pymavlink ground
station: one datagram cannot swallow the next, a forged signature cannot lock the ground station out, and
every command is answered. No wall-clock assertions: each test waits for events with generous deadlines."""

import math
import time

import pytest
from pymavlink.dialects.v20 import common as M

from vehicle_sim.harness import Gcs, VehicleThread, free_udp_port, thread_config
from vehicle_sim.link import SIGNING_EPOCH_S

KEY, WRONG_KEY = bytes(range(32)), bytes(range(100, 132))
ARM = M.MAV_CMD_COMPONENT_ARM_DISARM


def signed_bytes(msg, key: bytes, timestamp: int, *, link_id: int = 3, sysid: int = 255, compid: int = 190) -> bytes:
    """``msg`` signed with ``key`` on stream (sysid, compid, link_id) at ``timestamp`` (10 us units)."""
    mav = M.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    mav.signing.secret_key, mav.signing.sign_outgoing = key, True
    mav.signing.link_id, mav.signing.timestamp = link_id, timestamp
    return msg.pack(mav)


def now_timestamp() -> int:
    return int((time.time() - SIGNING_EPOCH_S) * 100_000)


def wait_for(cond, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise TimeoutError("condition not met")
        time.sleep(0.01)


def ack(gcs: Gcs, msg, timeout: float = 5.0):
    """Send a COMMAND_LONG/INT and return its COMMAND_ACK."""
    gcs.send(msg)
    return gcs.recv("COMMAND_ACK", lambda m: m.command == msg.command, timeout)


@pytest.fixture
def plain():
    gcs_port = free_udp_port()
    vt = VehicleThread(thread_config(free_udp_port(), gcs_port, speedup=5.0))
    with vt as vehicle, Gcs(gcs_port) as gcs:
        gcs.wait_vehicle()
        yield vehicle, gcs
    assert not vt.alive


# -- 1. the parser starts afresh with every datagram ---------------------------------------------------
@pytest.mark.io
def test_two_byte_datagram_does_not_swallow_the_next_command(plain):
    vehicle, gcs = plain
    gcs.send_raw(b"\xfd\xff")  # a MAVLink 2 start byte announcing a 255-byte payload, and nothing else
    assert gcs.command(ARM, 1) == M.MAV_RESULT_ACCEPTED
    gcs.recv("HEARTBEAT", lambda m: m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
    gcs.send_raw(b"\xfd\xff")
    assert gcs.command(ARM, 0) == M.MAV_RESULT_ACCEPTED
    gcs.recv("HEARTBEAT", lambda m: not m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
    assert vehicle.link.stats.bad_data >= 2


@pytest.mark.io
def test_one_datagram_with_two_messages_yields_both(plain):
    vehicle, gcs = plain
    first = M.MAVLink_command_long_message(1, 1, ARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(gcs.mav)
    gcs.mav.seq += 1
    second = M.MAVLink_ping_message(123, 42, 0, 0).pack(gcs.mav)
    gcs.send_raw(first + second)
    seen = set()
    deadline = time.monotonic() + 5
    while seen != {"ack", "ping"} and time.monotonic() < deadline:
        for m in gcs.poll():
            if m.get_type() == "COMMAND_ACK" and m.command == ARM and m.result == M.MAV_RESULT_ACCEPTED:
                seen.add("ack")
            elif m.get_type() == "PING" and m.seq == 42:
                seen.add("ping")
    assert seen == {"ack", "ping"}
    # and behind garbage in the same datagram: the parser resynchronises on the next start byte
    gcs.mav.seq += 1
    gcs.send_raw(b"\xfd\xff\x00" + M.MAVLink_ping_message(124, 43, 0, 0).pack(gcs.mav))
    assert gcs.recv("PING", lambda m: m.seq == 43).target_system == 255


# -- 2. a signature is verified before its timestamp counts ------------------------------------------
@pytest.mark.io
def test_forged_future_timestamp_does_not_lock_out_the_signed_gcs():
    gcs_port = free_udp_port()
    with VehicleThread(thread_config(free_udp_port(), gcs_port, speedup=5.0, signing_key=KEY)) as vehicle:
        with Gcs(gcs_port, signing_key=KEY) as gcs:
            gcs.wait_vehicle()
            assert gcs.command(ARM, 1) == M.MAV_RESULT_ACCEPTED  # the genuine stream exists
            forged = M.MAVLink_command_long_message(1, 1, ARM, 0, 0, 0, 0, 0, 0, 0, 0)
            gcs.send_raw(signed_bytes(forged, WRONG_KEY, 2**48 - 10))  # same stream id, wrong key
            wait_for(lambda: vehicle.link.stats.rejected_signature >= 1)
            assert vehicle.nav.armed
            assert gcs.command(ARM, 0) == M.MAV_RESULT_ACCEPTED  # still heard
            # a forgery on a stream never seen before must not open it either
            gcs.send_raw(signed_bytes(forged, WRONG_KEY, 2**48 - 10, link_id=9))
            wait_for(lambda: vehicle.link.stats.rejected_signature >= 2)
            assert gcs.command(ARM, 1) == M.MAV_RESULT_ACCEPTED
        with Gcs(gcs_port, signing_key=KEY) as restarted:  # fresh, time-based timestamp
            restarted.wait_vehicle()
            assert restarted.command(ARM, 0) == M.MAV_RESULT_ACCEPTED
            assert restarted.mav.signing.goodsig_count > 0  # and the vehicle's own signing clock is sane
        assert not vehicle.nav.armed
        assert all(ts < now_timestamp() + 60 * 100_000 for ep in vehicle.link.endpoints
                   for ts in ep.signature.streams.values())


@pytest.mark.io
def test_replayed_signed_command_is_refused():
    gcs_port = free_udp_port()
    with VehicleThread(thread_config(free_udp_port(), gcs_port, speedup=5.0, signing_key=KEY)) as vehicle, \
            Gcs(gcs_port, signing_key=KEY) as gcs:
        gcs.wait_vehicle()
        arm = M.MAVLink_command_long_message(1, 1, ARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(gcs.mav)
        gcs.send_raw(arm)
        assert gcs.recv("COMMAND_ACK", lambda m: m.command == ARM).result == M.MAV_RESULT_ACCEPTED
        assert gcs.command(ARM, 0) == M.MAV_RESULT_ACCEPTED
        before = vehicle.link.stats.rejected_signature
        gcs.send_raw(arm)  # captured and replayed
        wait_for(lambda: vehicle.link.stats.rejected_signature > before)
        assert not vehicle.nav.armed


# -- 3. every command is answered ---------------------------------------------------------------------
@pytest.mark.io
def test_every_command_gets_an_ack(plain):
    vehicle, gcs = plain
    nan, inf = math.nan, math.inf
    a = ack(gcs, M.MAVLink_command_long_message(1, 1, M.MAV_CMD_DO_SET_MODE, 0, nan, nan, nan, 0, 0, 0, 0))
    assert (a.result, a.result_param2) == (M.MAV_RESULT_DENIED, 1)  # param1 named
    assert "param1" in gcs.recv("STATUSTEXT", lambda m: "176" in m.text).text
    a = ack(gcs, M.MAVLink_command_long_message(1, 1, M.MAV_CMD_DO_SET_MODE, 0, 1, nan, 3, 0, 0, 0, 0))
    assert (a.result, a.result_param2) == (M.MAV_RESULT_DENIED, 2)
    a = ack(gcs, M.MAVLink_command_int_message(1, 1, 0, M.MAV_CMD_DO_SET_MODE, 0, 0, 1, 4, nan, 0, 0, 0, 0))
    assert (a.result, a.result_param2) == (M.MAV_RESULT_DENIED, 3)
    a = ack(gcs, M.MAVLink_command_long_message(1, 1, ARM, 0, nan, 0, 0, 0, 0, 0, 0))
    assert (a.result, a.result_param2) == (M.MAV_RESULT_DENIED, 1)
    a = ack(gcs, M.MAVLink_command_long_message(1, 1, M.MAV_CMD_MISSION_START, 0, inf, 0, 0, 0, 0, 0, 0))
    assert (a.result, a.result_param2) == (M.MAV_RESULT_DENIED, 1)
    a = ack(gcs, M.MAVLink_command_long_message(1, 1, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, -inf))
    assert a.result in (M.MAV_RESULT_DENIED, M.MAV_RESULT_TEMPORARILY_REJECTED)
    assert ack(gcs, M.MAVLink_command_long_message(1, 1, 31999, 0, nan, 0, 0, 0, 0, 0, 0)).result == \
        M.MAV_RESULT_UNSUPPORTED
    assert ack(gcs, M.MAVLink_command_int_message(1, 1, 0, 31998, 0, 0, 0, 0, 0, 0, 0, 0, 0)).result == \
        M.MAV_RESULT_UNSUPPORTED
    assert not vehicle.nav.armed
    # a valid set-mode after all that still works
    a = ack(gcs, M.MAVLink_command_long_message(1, 1, M.MAV_CMD_DO_SET_MODE, 0,
                                                M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 3, 0, 0, 0, 0))
    assert a.result == M.MAV_RESULT_ACCEPTED
