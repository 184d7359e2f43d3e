"""Offboard, orbit, geofence zones and rally points over real UDP with a bare pymavlink GCS (fast: the
MAVSDK examples test covers the same with MAVSDK-Python). Asserts on the vehicle's reported state and
its STATUSTEXTs, never on wall-clock durations."""

import math
import threading
import time

import pytest
from pymavlink.dialects.v20 import common as M

from radseek.coordinates import enu_to_geodetic
from vehicle_sim.geofence import Geofence
from vehicle_sim.harness import Gcs, VehicleThread, free_udp_port, thread_config
from vehicle_sim.navigator import Mode, px4_custom_mode

WAIT_S = 60.0  # bounds waiting only
POS_ONLY = 0b0000_1101_1111_1000  # ignore velocity, acceleration, yaw rate (MAVSDK's position setpoint)


@pytest.fixture
def setup():
    gcs_port = free_udp_port()
    cfg = thread_config(free_udp_port(), gcs_port, speedup=5.0, fence=Geofence(-100, -100, 0, 100, 100, 50))
    vt = VehicleThread(cfg)
    with vt as vehicle, Gcs(gcs_port, keepalive=True) as gcs:
        gcs.wait_vehicle()
        yield vehicle, gcs


def _setpoint(n, e, d):
    return M.MAVLink_set_position_target_local_ned_message(0, 1, 1, M.MAV_FRAME_LOCAL_NED, POS_ONLY, n, e, d,
                                                           0, 0, 0, 0, 0, 0, 0.0, 0.0)


def _command_int(gcs: Gcs, command: int, p1, p2, p3, p4, lat: float, lon: float, alt: float) -> int:
    """COMMAND_INT, as MAVSDK sends positions (COMMAND_LONG's float32 lat/lon is only good to ~0.4 m)."""
    gcs.send(M.MAVLink_command_int_message(1, 1, M.MAV_FRAME_GLOBAL, command, 0, 0, p1, p2, p3, p4,
                                           int(round(lat * 1e7)), int(round(lon * 1e7)), alt))
    return gcs.recv("COMMAND_ACK", lambda m: m.command == command, WAIT_S).result


def _text(gcs: Gcs, part: str):
    """A STATUSTEXT containing ``part``: already received (while waiting for an ACK) or still to come."""
    for m in gcs.received:
        if m.get_type() == "STATUSTEXT" and part in m.text:
            return m
    return gcs.recv("STATUSTEXT", lambda m: part in m.text, WAIT_S)


@pytest.mark.io
def test_offboard_needs_a_stream_and_holds_when_it_stops(setup):
    vehicle, gcs = setup
    offboard = (1, 6, 0)
    assert gcs.command(M.MAV_CMD_DO_SET_MODE, *offboard) == M.MAV_RESULT_DENIED  # no stream yet
    _text(gcs, "command 176 refused: offboard")  # (the rest of the reason follows in a second chunk)
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    stop = threading.Event()

    def stream():  # 20 Hz of wall time, like MAVSDK
        while not stop.is_set():
            gcs.send(_setpoint(3.0, 0.0, -4.0))
            time.sleep(0.05)

    streamer = threading.Thread(target=stream, daemon=True)
    streamer.start()
    try:
        time.sleep(0.3)
        assert gcs.command(M.MAV_CMD_DO_SET_MODE, *offboard) == M.MAV_RESULT_ACCEPTED
        gcs.recv("LOCAL_POSITION_NED", lambda m: abs(m.x - 3) < 0.2 and abs(m.z + 4) < 0.2, WAIT_S)
        gcs.recv("HEARTBEAT", lambda m: m.custom_mode == px4_custom_mode(Mode.OFFBOARD), WAIT_S)
    finally:
        stop.set()
        streamer.join(5)
    _text(gcs, "Failsafe: offboard setpoints lost")
    gcs.recv("HEARTBEAT", lambda m: m.custom_mode == px4_custom_mode(Mode.HOLD), WAIT_S)
    assert vehicle.nav.in_air  # holds in the air, does not drop


@pytest.mark.io
def test_fence_zones_refuse_items_and_gotos_and_rtl_lands_at_the_rally_point(setup):
    vehicle, gcs = setup
    home = vehicle.home

    def ll(x, y):
        lat, lon, _ = enu_to_geodetic(home, (x, y, 0.0))
        return int(round(lat * 1e7)), int(round(lon * 1e7))

    def upload(items, mtype):
        gcs.send(M.MAVLink_mission_count_message(1, 1, len(items), mtype))
        while True:
            m = gcs.recv({"MISSION_REQUEST_INT", "MISSION_ACK"}, lambda m: m.mission_type == mtype, WAIT_S)
            if m.get_type() == "MISSION_ACK":
                return m.type
            gcs.send(items[m.seq])

    def fence_item(seq, cmd, x, y, p1):
        return M.MAVLink_mission_item_int_message(1, 1, seq, M.MAV_FRAME_GLOBAL_INT, cmd, 0, 1, p1, 0, 0, 0,
                                                  *ll(x, y), 0.0, 1)

    square = [(-40, -40), (40, -40), (40, 40), (-40, 40)]
    fence = [fence_item(k, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, x, y, 4) for k, (x, y) in enumerate(square)]
    fence.append(fence_item(4, M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, 20, 0, 5.0))
    bad = [fence_item(0, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, 0, 0, 4)]  # 1 item announcing 4 vertices
    assert upload(bad, 1) == M.MAV_MISSION_INVALID_PARAM1
    assert upload(fence, 1) == M.MAV_MISSION_ACCEPTED
    _text(gcs, "Geofence: 2 zone(s) uploaded")

    def wp(x, y, z=5.0):
        return M.MAVLink_mission_item_int_message(1, 1, 0, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                                  M.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0, 0, math.nan, *ll(x, y), z, 0)

    assert upload([wp(20, 1)], 0) == M.MAV_MISSION_DENIED  # inside the exclusion circle
    _text(gcs, "inside exclusion fence")
    assert upload([wp(0, 60)], 0) == M.MAV_MISSION_DENIED  # outside the inclusion square (inside the box)
    assert upload([wp(0, 150)], 0) == M.MAV_MISSION_INVALID_PARAM5_X  # north: latitude, param5
    assert upload([wp(150, 0)], 0) == M.MAV_MISSION_INVALID_PARAM6_Y  # east: longitude, param6
    rally = [M.MAVLink_mission_item_int_message(1, 1, 0, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                                M.MAV_CMD_NAV_RALLY_POINT, 0, 1, 0, 0, 0, 0, *ll(-10, 5), 3.0, 2)]
    assert upload(rally, 2) == M.MAV_MISSION_ACCEPTED
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    assert gcs.command(M.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 7) == M.MAV_RESULT_ACCEPTED
    gcs.recv("EXTENDED_SYS_STATE", lambda m: m.landed_state == M.MAV_LANDED_STATE_IN_AIR, WAIT_S)
    lat, lon = ll(20, 0)
    amsl = home.alt_m + 5.0
    assert _command_int(gcs, M.MAV_CMD_DO_REPOSITION, -1, 0, 0, math.nan, lat / 1e7, lon / 1e7, amsl) == \
        M.MAV_RESULT_DENIED  # into the exclusion circle
    _text(gcs, "outside the geofence")
    assert gcs.command(M.MAV_CMD_DO_ORBIT, 0.5, 1, 0, math.nan, math.nan, math.nan, math.nan) == \
        M.MAV_RESULT_DENIED  # radius below 1 m
    assert _command_int(gcs, M.MAV_CMD_DO_ORBIT, 10, 1, 0, math.nan, *(v / 1e7 for v in ll(20, 0)), amsl) == \
        M.MAV_RESULT_DENIED  # circle crosses the exclusion zone
    lat, lon = ll(-8, 4)  # nearer the rally point (-10, 5) than home
    assert _command_int(gcs, M.MAV_CMD_DO_REPOSITION, -1, 0, 0, math.nan, lat / 1e7, lon / 1e7, amsl) == \
        M.MAV_RESULT_ACCEPTED
    gcs.recv("LOCAL_POSITION_NED", lambda m: math.hypot(m.y + 8, m.x - 4) < 0.3, WAIT_S)
    assert gcs.command(M.MAV_CMD_NAV_RETURN_TO_LAUNCH) == M.MAV_RESULT_ACCEPTED
    gcs.recv("EXTENDED_SYS_STATE", lambda m: m.landed_state == M.MAV_LANDED_STATE_ON_GROUND, WAIT_S)
    p = gcs.recv("LOCAL_POSITION_NED", timeout=WAIT_S)
    assert math.hypot(p.y + 10, p.x - 5) < 0.5 and p.z > -0.05  # landed at the nearest safe point: the rally point


@pytest.mark.io
def test_orbit_circles_the_centre(setup):
    vehicle, gcs = setup
    assert gcs.command(M.MAV_CMD_DO_ORBIT, 5, 2, 0, math.nan, math.nan, math.nan, math.nan) == M.MAV_RESULT_DENIED
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    assert gcs.command(M.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 7) == M.MAV_RESULT_ACCEPTED
    gcs.recv("HEARTBEAT", lambda m: m.custom_mode == px4_custom_mode(Mode.HOLD), WAIT_S)
    lat, lon, _ = enu_to_geodetic(vehicle.home, (10.0, 0.0, 0.0))
    assert _command_int(gcs, M.MAV_CMD_DO_ORBIT, -5, 2, 0, math.nan, lat, lon, vehicle.home.alt_m + 4) == \
        M.MAV_RESULT_ACCEPTED  # negative radius: counter-clockwise
    _text(gcs, "Orbit: circling r=5.0 m")
    gcs.recv("HEARTBEAT", lambda m: m.custom_mode == px4_custom_mode(Mode.ORBIT), WAIT_S)
    angles = []
    while len(angles) < 30:
        p = gcs.recv("LOCAL_POSITION_NED", timeout=WAIT_S)  # NED: x north, y east
        assert math.hypot(p.y - 10, p.x) == pytest.approx(5.0, abs=0.05) and p.z == pytest.approx(-4, abs=0.05)
        angles.append(math.atan2(p.x, p.y - 10))
    assert sum(math.remainder(b - a, 2 * math.pi) for a, b in zip(angles, angles[1:], strict=False)) > 0  # CCW


def test_mapped_walls_become_exclusion_fences():
    from detector_fw_sim.scene import load_scene
    from radseek_cli import vehicle_cli
    from vehicle_sim.geofence import wall_zones

    walls = load_scene("lattice-wall").walls  # (5.6, 3.4)-(5.6, 4.5) and (4.5, 3.4)-(5.505, 3.4), 0.19 m thick
    zones = wall_zones(walls, margin=0.3)
    assert len(zones) == 2 and not any(z.inclusion for z in zones)
    fence = Geofence(0, 0, 0, 10, 8, 5).with_zones(zones)
    assert not fence.contains((5.6, 4.0, 1.0)) and not fence.contains((5.6 + 0.39, 4.0, 1.0))  # wall + margin
    assert fence.contains((5.6 + 0.45, 4.0, 1.0)) and fence.contains((2.0, 2.0, 1.0))
    args = vehicle_cli.build_parser().parse_args(["--scene", "lattice-wall", "--wall-fence", "--no-zenoh"])
    assert len(vehicle_cli.config_from_args(args).fence.zones) == 2
    assert vehicle_cli.main(["--wall-fence", "--no-zenoh"]) == 2  # walls need a scene
