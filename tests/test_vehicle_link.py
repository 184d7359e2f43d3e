"""The vehicle over real UDP on loopback, with a bare pymavlink ground station: telemetry content,
commands and their ACKs, parameters, malformed input, and MAVLink 2 signing."""

import math
import os
import socket
import threading
import time

import pytest
from pymavlink.dialects.v20 import common as M

from vehicle_sim.geofence import Geofence
from vehicle_sim.harness import Gcs, VehicleThread, free_udp_port, thread_config
from vehicle_sim.navigator import Mode, px4_custom_mode

TELEMETRY = {"HEARTBEAT", "SYS_STATUS", "BATTERY_STATUS", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE",
             "ODOMETRY", "EXTENDED_SYS_STATE", "MISSION_CURRENT", "HOME_POSITION"}


@pytest.fixture
def flying_setup():
    gcs_port = free_udp_port()
    cfg = thread_config(free_udp_port(), gcs_port, speedup=10.0, fence=Geofence(-100, -100, 0, 100, 100, 50))
    vt = VehicleThread(cfg)
    with vt as vehicle, Gcs(gcs_port) as gcs:
        gcs.wait_vehicle()
        yield vehicle, gcs, vt
    assert not vt.alive


@pytest.mark.io
def test_telemetry_streams_and_autopilot_identity(flying_setup):
    vehicle, gcs, _ = flying_setup
    deadline = time.monotonic() + 60  # bounds the wait only
    while not TELEMETRY <= {m.get_type() for m in gcs.received} and time.monotonic() < deadline:
        gcs.poll()
    seen = {m.get_type(): m for m in gcs.received}
    assert TELEMETRY <= set(seen)
    hb = seen["HEARTBEAT"]
    assert (hb.autopilot, hb.type) == (M.MAV_AUTOPILOT_PX4, M.MAV_TYPE_QUADROTOR)
    assert hb.get_srcComponent() == 1 and hb.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert hb.custom_mode == px4_custom_mode(Mode.HOLD)
    odo = seen["ODOMETRY"]
    assert odo.pose_covariance[0] > 0 and odo.estimator_type == M.MAV_ESTIMATOR_TYPE_VIO
    assert seen["HOME_POSITION"].latitude == 473977420
    assert seen["EXTENDED_SYS_STATE"].landed_state == M.MAV_LANDED_STATE_ON_GROUND
    assert seen["MISSION_CURRENT"].mission_state == 1  # NO_MISSION
    assert gcs.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == M.MAV_RESULT_ACCEPTED
    av = gcs.recv("AUTOPILOT_VERSION")
    assert av.capabilities & M.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    assert gcs.command(M.MAV_CMD_REQUEST_MESSAGE, 9999) == M.MAV_RESULT_UNSUPPORTED
    # SET_MESSAGE_INTERVAL out of range (not -1, 0 or 1 ms..60 s) is denied, not taken
    for bad in (-1e30, -2.0, 10.0, 1e12):
        assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, bad) == M.MAV_RESULT_DENIED
    # SET_MESSAGE_INTERVAL: -1 switches a stream off
    assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, -1) == M.MAV_RESULT_ACCEPTED
    # everything after the ACK was sent after the change: over 1 s of sim time (the stamps of
    # GLOBAL_POSITION_INT, which stays on) not one ATTITUDE, however slowly the host runs
    gcs.received.clear()
    first = gcs.recv("GLOBAL_POSITION_INT").time_boot_ms
    gcs.recv("GLOBAL_POSITION_INT", lambda m: m.time_boot_ms >= first + 1000)
    assert "ATTITUDE" not in {m.get_type() for m in gcs.received}


@pytest.mark.io
def test_commands_fly_and_answer(flying_setup):
    vehicle, gcs, _ = flying_setup
    assert gcs.command(M.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 7) == M.MAV_RESULT_TEMPORARILY_REJECTED  # disarmed
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    assert gcs.recv("HEARTBEAT", lambda m: m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
    assert gcs.command(M.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 7) == M.MAV_RESULT_ACCEPTED
    gcs.recv("EXTENDED_SYS_STATE", lambda m: m.landed_state == M.MAV_LANDED_STATE_IN_AIR)
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0) == M.MAV_RESULT_DENIED  # in the air
    assert gcs.command(31999) == M.MAV_RESULT_UNSUPPORTED
    assert gcs.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0) == M.MAV_RESULT_DENIED  # offboard: no setpoint stream yet
    assert gcs.command(M.MAV_CMD_DO_SET_MODE, 1, 9, 0) == M.MAV_RESULT_UNSUPPORTED  # no such PX4 main mode
    assert gcs.command(M.MAV_CMD_DO_SET_MODE, 0, 4, 3) == M.MAV_RESULT_DENIED  # no custom-mode flag
    home = vehicle.home
    # go-to outside the geofence is denied, inside accepted and flown
    assert gcs.command(M.MAV_CMD_DO_REPOSITION, -1, 0, 0, math.nan, home.lat_deg + 0.01, home.lon_deg,
                       home.alt_m + 5) == M.MAV_RESULT_DENIED
    assert gcs.command(M.MAV_CMD_DO_REPOSITION, -1, 0, 0, 90.0, home.lat_deg + 0.0001, home.lon_deg,
                       home.alt_m + 5) == M.MAV_RESULT_ACCEPTED  # 11.1 m north, facing east
    gcs.recv("LOCAL_POSITION_NED", lambda m: abs(m.x - 11.12) < 0.3 and abs(m.z + 5) < 0.3)
    att = gcs.recv("ATTITUDE", lambda m: abs(m.yaw - math.pi / 2) < 0.05)
    assert att is not None
    assert gcs.command(M.MAV_CMD_NAV_RETURN_TO_LAUNCH) == M.MAV_RESULT_ACCEPTED
    gcs.recv("HEARTBEAT", lambda m: m.custom_mode == px4_custom_mode(Mode.RTL))
    gcs.recv("HEARTBEAT", lambda m: not m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)  # landed, disarmed
    lp = gcs.recv("LOCAL_POSITION_NED")
    assert abs(lp.x) < 0.3 and abs(lp.y) < 0.3 and abs(lp.z) < 0.05
    assert gcs.command(M.MAV_CMD_NAV_LAND) == M.MAV_RESULT_DENIED  # already on the ground


@pytest.mark.io
def test_parameters(flying_setup):
    _, gcs, _ = flying_setup
    gcs.send(M.MAVLink_param_request_list_message(1, 1))
    values = {}
    total = 1
    while len(values) < total:  # the whole list, however long (param_count)
        m = gcs.recv("PARAM_VALUE")
        values[m.param_id], total = m, m.param_count
    assert {"MIS_TAKEOFF_ALT", "COM_OF_LOSS_T"} <= set(values)
    assert values["MIS_TAKEOFF_ALT"].param_value == pytest.approx(2.5)
    gcs.send(M.MAVLink_param_set_message(1, 1, b"MIS_TAKEOFF_ALT", 4.0, M.MAV_PARAM_TYPE_REAL32))
    assert gcs.recv("PARAM_VALUE").param_value == pytest.approx(4.0)
    gcs.send(M.MAVLink_param_set_message(1, 1, b"MIS_TAKEOFF_ALT", 1e6, M.MAV_PARAM_TYPE_REAL32))
    assert gcs.recv("PARAM_VALUE").param_value == pytest.approx(4.0)  # out of bounds: refused
    gcs.send(M.MAVLink_param_request_read_message(1, 1, b"", 0))
    assert gcs.recv("PARAM_VALUE").param_index == 0
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    assert gcs.command(M.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 7) == M.MAV_RESULT_ACCEPTED
    gcs.recv("LOCAL_POSITION_NED", lambda m: abs(m.z + 4.0) < 0.25)  # the new takeoff altitude


@pytest.mark.io
def test_malformed_input_never_stops_the_vehicle(flying_setup):
    vehicle, gcs, vt = flying_setup
    good = M.MAVLink_ping_message(1, 7, 0, 0).pack(M.MAVLink(None, 255, 190))
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    junk = [os.urandom(n) for n in (1, 5, 40, 300)]
    mav1 = M.MAVLink(None, 255, 190)
    mav1.WIRE_PROTOCOL_VERSION = "1.0"
    v1 = M.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav1, force_mavlink1=True)
    for data in [*junk, bytes(bad_crc), good[:7], b"\xfd" + b"\xff" * 30, bytes(300), v1[:-3]]:
        gcs.send_raw(data)
    # nonsense values inside well-formed messages
    gcs.send(M.MAVLink_command_long_message(1, 1, M.MAV_CMD_DO_SET_MISSION_CURRENT, 0, math.nan, 0, 0, 0, 0, 0, 0))
    gcs.send(M.MAVLink_mission_item_int_message(1, 1, 3, 6, 16, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0))  # no upload
    gcs.send(M.MAVLink_mission_set_current_message(1, 1, 50))
    gcs.send(M.MAVLink_param_request_read_message(1, 1, b"", 500))
    gcs.send(M.MAVLink_set_mode_message(1, 1, 0xFFFFFFFF))
    gcs.send(M.MAVLink_command_long_message(7, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))  # other system: not for us
    gcs.send(M.MAVLink_ping_message(123, 9, 0, 0))
    assert gcs.recv("PING", lambda m: m.seq == 9).target_system == 255
    assert vt.alive and not vehicle.nav.armed
    assert vehicle.link.stats.bad_data >= 4
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED


@pytest.mark.io
def test_signing_refuses_unsigned_and_wrongly_signed_commands():
    key, other = bytes(range(32)), bytes(range(1, 33))
    gcs_port = free_udp_port()
    cfg = thread_config(free_udp_port(), gcs_port, speedup=5.0, signing_key=key)
    with VehicleThread(cfg) as vehicle, Gcs(gcs_port) as plain:
        hb = plain.recv("HEARTBEAT")  # we can read its (signed) messages without the key
        assert hb is not None
        plain.send(M.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
        with pytest.raises(TimeoutError):
            plain.recv("COMMAND_ACK", timeout=0.5)
        assert vehicle.link.stats.rejected_signature >= 1 and not vehicle.nav.armed
        plain.close()
        with Gcs(gcs_port, signing_key=other) as wrong:
            wrong.wait_vehicle()
            wrong.send(M.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
            with pytest.raises(TimeoutError):
                wrong.recv("COMMAND_ACK", timeout=0.5)
        assert not vehicle.nav.armed
        with Gcs(gcs_port, signing_key=key) as signed:
            signed.wait_vehicle()
            assert signed.mav.signing.goodsig_count > 0  # the vehicle signs what it sends
            assert signed.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
        assert vehicle.nav.armed


@pytest.mark.io
def test_a_remote_given_by_name_is_sent_to_by_address():
    """compose starts the vehicle with --remote-host mission: the link resolves the name once, off the sim loop,
    and hands sendto the address (a name in sendto is looked up again for every datagram, on the sim loop)."""
    gcs_port = free_udp_port()
    with VehicleThread(thread_config(free_udp_port(), gcs_port, remote_host="localhost")) as vehicle, \
            Gcs(gcs_port) as gcs:
        gcs.recv("HEARTBEAT")
        assert vehicle.link.endpoints[1].remote == ("127.0.0.1", gcs_port)
        assert vehicle.link.endpoints[1].target == ("localhost", gcs_port)


@pytest.mark.io
def test_a_name_the_resolver_never_answers_stops_neither_the_clock_nor_the_replies(monkeypatch):
    """Under Docker, once the mission's container had stopped, its name took the resolver 10 s a lookup; looked up
    by every sendto, that stopped the compose vehicle's clock, and so the detector's spectra. Here the resolver
    never answers: the vehicle still steps, counts what it could not send, and answers a GCS that speaks to it."""
    resolver_answers = threading.Event()
    real = socket.getaddrinfo

    def hung(host, *args, **kwargs):
        if host == "mission":
            resolver_answers.wait()
            raise socket.gaierror(socket.EAI_AGAIN, "Temporary failure in name resolution")
        return real(host, *args, **kwargs)

    monkeypatch.setattr(socket, "getaddrinfo", hung)
    gcs_port = free_udp_port()
    try:
        with VehicleThread(thread_config(free_udp_port(), gcs_port, speedup=10.0, remote_host="mission")) as vehicle, \
                Gcs(gcs_port) as gcs:
            deadline = time.monotonic() + 60  # bounds the wait only
            while (vehicle.t < 5.0 or vehicle.link.stats.unresolved_tx == 0) and time.monotonic() < deadline:
                time.sleep(0.05)
            assert vehicle.t >= 5.0 and vehicle.link.stats.unresolved_tx > 0
            assert vehicle.link.stats.tx_packets == 0  # nothing went anywhere: no peer, no address
            host, port = vehicle.link.endpoints[1].local_address
            gcs.vehicle_addr = ("127.0.0.1" if host == "0.0.0.0" else host, port)
            assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
            assert vehicle.link.endpoints[1].remote == ("127.0.0.1", gcs_port)
    finally:
        resolver_answers.set()
