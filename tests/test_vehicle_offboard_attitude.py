"""Attitude and body-rate offboard (SET_ATTITUDE_TARGET): analytic cases of the point-mass model, the decoding of
the message, and a flight over real UDP where the vehicle rolls as told and ATTITUDE reports it."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as M

from vehicle_sim.harness import Gcs, VehicleThread, free_udp_port, thread_config
from vehicle_sim.navigator import Mode, px4_custom_mode
from vehicle_sim.offboard import (
    DRAG_PER_S,
    GRAVITY,
    AttitudeTarget,
    SetpointError,
    attitude_setpoint_from_msg,
    attitude_step,
    euler_from_quaternion,
    lifts_off,
)

HOVER = 0.5
DT = 0.05


def _quat(roll: float, pitch: float, yaw: float) -> list[float]:
    cr, sr, cp, sp, cy, sy = (math.cos(roll / 2), math.sin(roll / 2), math.cos(pitch / 2), math.sin(pitch / 2),
                              math.cos(yaw / 2), math.sin(yaw / 2))
    return [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy]


def _fly(target: AttitudeTarget, seconds: float, z0: float = 10.0):
    pos, vel, att = np.array([0.0, 0.0, z0]), np.zeros(3), (0.0, 0.0, 0.0)
    for _ in range(round(seconds / DT)):
        pos, vel, att = attitude_step(pos, vel, att, target, HOVER, DT)
    return pos, vel, att


def test_level_at_hover_thrust_holds_and_more_thrust_climbs():
    pos, vel, _ = _fly(AttitudeTarget((0.0, 0.0, 0.0), None, HOVER), 5.0)
    assert np.allclose(pos, [0, 0, 10]) and np.allclose(vel, 0)
    _, vel, _ = _fly(AttitudeTarget((0.0, 0.0, 0.0), None, 0.7), 0.05)
    assert vel[2] == pytest.approx(GRAVITY * (0.7 / HOVER - 1) * DT)  # first step from rest: no drag yet


def test_a_right_roll_facing_north_accelerates_east_to_the_drag_terminal_speed():
    roll = math.radians(30)
    thrust = HOVER / math.cos(roll)  # the vertical share of the thrust holds the altitude
    _, vel, _ = _fly(AttitudeTarget((roll, 0.0, 0.0), None, thrust), DT)
    assert vel[0] == pytest.approx(GRAVITY * math.tan(roll) * DT) and abs(vel[1]) < 1e-12
    pos, vel, _ = _fly(AttitudeTarget((roll, 0.0, 0.0), None, thrust), 30.0)
    assert vel[0] == pytest.approx(GRAVITY * math.tan(roll) / DRAG_PER_S, rel=1e-3)
    assert pos[2] == pytest.approx(10.0) and abs(pos[1]) < 1e-9
    # nose down (negative pitch) facing east (yaw 90 deg NED): forward is east
    _, vel, _ = _fly(AttitudeTarget((0.0, -roll, math.pi / 2), None, thrust), 1.0)
    assert vel[0] > 1.0 and abs(vel[1]) < 1e-9


def test_body_rates_integrate_into_the_attitude_and_the_ground_stops_a_fall():
    _, _, att = _fly(AttitudeTarget(None, (0.2, 0.0, -0.5), HOVER), 1.0)
    assert att[0] == pytest.approx(0.2) and att[2] == pytest.approx(-0.5)
    pos, vel, _ = _fly(AttitudeTarget((0.0, 0.0, 0.0), None, 0.0), 10.0, z0=2.0)
    assert pos[2] == 0.0 and np.allclose(vel, 0)
    assert not lifts_off(AttitudeTarget((0.0, 0.0, 0.0), None, HOVER), HOVER)
    assert lifts_off(AttitudeTarget((0.0, 0.0, 0.0), None, 0.6), HOVER)
    assert not lifts_off(AttitudeTarget((math.radians(40), 0.0, 0.0), None, 0.6), HOVER)  # 0.6 cos 40 < 0.5


def test_set_attitude_target_decoding():
    q = _quat(math.radians(30), math.radians(-10), math.radians(45))
    assert euler_from_quaternion(q) == pytest.approx((math.radians(30), math.radians(-10), math.radians(45)))
    msg = M.MAVLink_set_attitude_target_message(0, 1, 1, 0b111, q, 0, 0, 0, 0.6)  # MAVSDK's set_attitude
    sp = attitude_setpoint_from_msg(msg)
    assert sp.pos is None and sp.vel is None and sp.attitude.thrust == pytest.approx(0.6)
    assert sp.attitude.attitude == pytest.approx(euler_from_quaternion(q)) and sp.attitude.rates is None
    rates = attitude_setpoint_from_msg(M.MAVLink_set_attitude_target_message(0, 1, 1, 1 << 7, [1, 0, 0, 0],
                                                                             0.1, 0.2, 0.3, 0.5))
    assert rates.attitude.attitude is None and rates.attitude.rates == pytest.approx((0.1, 0.2, 0.3))
    for bad in (M.MAVLink_set_attitude_target_message(0, 1, 1, 0b111, [0, 0, 0, 0], 0, 0, 0, 0.5),
                M.MAVLink_set_attitude_target_message(0, 1, 1, 0b111, q, 0, 0, 0, 1.5),
                M.MAVLink_set_attitude_target_message(0, 1, 1, 0b111 | 1 << 7, q, 0, 0, 0, 0.5)):
        with pytest.raises(SetpointError):
            attitude_setpoint_from_msg(bad)


@pytest.mark.io
def test_attitude_offboard_over_udp_rolls_the_vehicle_east():
    gcs_port = free_udp_port()
    with VehicleThread(thread_config(free_udp_port(), gcs_port, speedup=5.0)) as vehicle, Gcs(gcs_port) as gcs:
        gcs.wait_vehicle()

        def stream(roll_deg: float, thrust: float, seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                gcs.send(M.MAVLink_set_attitude_target_message(0, 1, 1, 0b111, _quat(math.radians(roll_deg), 0, 0),
                                                               0, 0, 0, thrust))
                gcs.poll(0.02)

        assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0
        stream(0, 0.0, 0.3)
        offboard = px4_custom_mode(Mode.OFFBOARD)
        assert gcs.command(M.MAV_CMD_DO_SET_MODE, 1, (offboard >> 16) & 0xFF, offboard >> 24) == 0
        stream(0, 0.6, 1.0)  # up
        z_up = vehicle.nav.pos[2]
        assert z_up > 1.0 and abs(vehicle.nav.pos[0]) < 1e-6
        stream(20, 0.55, 1.0)  # rolled right: east
        assert vehicle.nav.pos[0] > 1.0
        att = gcs.recv("ATTITUDE", timeout=5)
        assert att.roll == pytest.approx(math.radians(20), abs=1e-6)
