"""Pure vehicle models: trapezoidal arrival times, limits, odometry drift statistics, battery, frames,
and the navigator's mission timing (arrival + hold) in sim time."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as M

from radseek import coordinates as frames
from vehicle_sim import battery, motion
from vehicle_sim.mission_protocol import MissionItem
from vehicle_sim.navigator import Mode, Navigator, NavParams
from vehicle_sim.odometry import Odometry, OdometryParams, propagate

DT = 0.05


def fly(target, limits, pos=None, yaw=0.0, target_yaw=None, max_t=200.0):
    pos = np.zeros(3) if pos is None else np.array(pos, float)
    vel = np.zeros(3)
    t, speeds, accels = 0.0, [], []
    while t < max_t:
        new_pos, new_vel, yaw = motion.step(pos, vel, yaw, np.array(target, float), target_yaw, limits, DT)
        accels.append(np.linalg.norm(new_vel - vel) / DT)
        pos, vel = new_pos, new_vel
        speeds.append(vel.copy())
        t += DT
        if motion.arrived(pos, vel, target, radius=0.01, speed=0.05) and (
                target_yaw is None or abs(frames.wrap_pi(target_yaw - yaw)) < 1e-6):
            return t, pos, np.array(speeds), np.array(accels), yaw
    raise AssertionError("never arrived")


@pytest.mark.parametrize("distance", [2.0, 30.0, 100.0])
def test_straight_leg_arrival_time_matches_trapezoid(distance):
    lim = motion.MotionLimits(max_speed_xy=4.0, max_accel=2.0)
    t, pos, speeds, accels, _ = fly([distance, 0, 0], lim)
    expected = motion.straight_leg_time(distance, 4.0, 2.0)
    assert abs(t - expected) < 0.25, (t, expected)
    assert np.linalg.norm(pos - [distance, 0, 0]) < 0.01
    assert np.max(np.linalg.norm(speeds[:, :2], axis=1)) <= 4.0 + 1e-9
    assert np.max(accels) <= 2.0 + 1e-9


def test_climb_uses_vertical_limit():
    lim = motion.MotionLimits(max_speed_xy=5.0, max_speed_up=1.0, max_accel=2.0)
    t, *_ = fly([0, 0, 20], lim)
    assert abs(t - motion.straight_leg_time(20, 1.0, 2.0)) < 0.25
    # a diagonal climb is limited by whichever axis saturates first
    d = np.array([10.0, 0, 10.0]) / math.sqrt(200)
    assert motion.direction_speed_limit(d, lim) == pytest.approx(1.0 / d[2])


def test_yaw_rate_limited():
    lim = motion.MotionLimits(max_yaw_rate=math.radians(30))
    t, _, _, _, yaw = fly([0, 0, 0], lim, yaw=0.0, target_yaw=math.pi / 2)
    assert yaw == pytest.approx(math.pi / 2)
    assert t == pytest.approx(3.0, abs=DT + 1e-9)


def test_limits_validated():
    with pytest.raises(ValueError):
        motion.MotionLimits(max_accel=0)


def test_odometry_no_drift_while_hovering_and_variance_linear_in_distance():
    odo = Odometry(OdometryParams(sigma_xy=0.1), seed=3)
    odo.advance(0.0)
    assert np.all(odo.drift == 0)
    for _ in range(100):
        odo.advance(0.5)
    assert odo.var[0] == pytest.approx(1e-4 + 0.01 * 50)
    # same seed, same drift (determinism)
    odo2 = Odometry(OdometryParams(sigma_xy=0.1), seed=3)
    for _ in range(100):
        odo2.advance(0.5)
    assert np.array_equal(odo.drift, odo2.drift)


def test_odometry_reported_variance_matches_actual_drift_spread():
    p = OdometryParams(sigma_xy=0.05)
    rng = np.random.default_rng(1)
    n, steps, ds = 4000, 50, 0.4
    drift, var = np.zeros((n, 4)), np.zeros((n, 4))
    for _ in range(steps):
        drift, var = propagate(drift, var, ds, rng.standard_normal((n, 4)), p)
    emp = drift[:, 0].var()
    assert emp == pytest.approx(var[0, 0], rel=0.1)  # 4000 samples: ~2.2 % standard error


def test_battery_drains_with_flight_time_and_speed():
    p = battery.BatteryParams(hover_endurance_s=100.0)
    assert battery.drain(1.0, 10.0, armed=False, in_air=False, speed=0, p=p) == 1.0
    hover = battery.drain(1.0, 10.0, armed=True, in_air=True, speed=0, p=p)
    fast = battery.drain(1.0, 10.0, armed=True, in_air=True, speed=5, p=p)
    idle = battery.drain(1.0, 10.0, armed=True, in_air=False, speed=0, p=p)
    assert hover == pytest.approx(0.9)
    assert fast < hover < idle < 1.0
    assert battery.voltage(1.0, p) == pytest.approx(16.8)


def test_frames_round_trip_and_conventions():
    home = frames.Home()
    p = np.array([120.0, -40.0, 7.0])
    lat, lon, alt = frames.enu_to_geodetic(home, p)
    assert lat < home.lat_deg and lon > home.lon_deg and alt == pytest.approx(home.alt_m + 7)
    assert np.allclose(frames.geodetic_to_enu(home, lat, lon, alt), p, atol=1e-6)
    assert np.allclose(frames.enu_to_ned([1, 2, 3]), [2, 1, -3])
    assert frames.yaw_enu_to_ned(0.0) == pytest.approx(math.pi / 2)  # east
    assert frames.yaw_enu_to_ned(math.pi / 2) == pytest.approx(0.0)  # north
    assert frames.yaw_ned_to_enu(frames.yaw_enu_to_ned(2.0)) == pytest.approx(2.0)


def _wp(seq, home, x, y, z, hold=0.0, cmd=M.MAV_CMD_NAV_WAYPOINT):
    lat, lon, _ = frames.enu_to_geodetic(home, (x, y, z))
    return MissionItem(seq, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, cmd, hold, 0, 0, math.nan,
                       int(round(lat * 1e7)), int(round(lon * 1e7)), z)


def run_nav(nav, until, t=0.0, max_t=500.0):
    while t < max_t:
        nav.step(t, DT)
        t += DT
        if until(nav):
            return t
    raise AssertionError("condition never met")


def test_mission_arrival_and_hold_times():
    home = frames.Home()
    lim = motion.MotionLimits(max_speed_xy=4.0, max_speed_up=2.0, max_accel=2.0)
    nav = Navigator(home, lim, NavParams(acceptance_radius=0.05))
    items = [_wp(0, home, 0, 0, 4.0, cmd=M.MAV_CMD_NAV_TAKEOFF), _wp(1, home, 30, 0, 4.0, hold=7.0),
             _wp(2, home, 30, 0, 4.0, hold=3.0, cmd=M.MAV_CMD_NAV_LOITER_TIME)]
    nav.replace_mission(items)
    nav.arm()
    assert nav.start_mission()
    reached = []
    t = 0.0
    while not nav.complete:
        nav.step(t, DT)
        t += DT
        reached += [(s, t) for k, s in nav.events if k == "reached"]
        nav.events.clear()
        assert t < 100
    takeoff = motion.straight_leg_time(4.0, 2.0, 2.0)
    leg = motion.straight_leg_time(30.0, 4.0, 2.0)
    assert [s for s, _ in reached] == [0, 1, 2]
    assert reached[0][1] == pytest.approx(takeoff, abs=0.3)
    assert reached[1][1] == pytest.approx(takeoff + leg + 7.0, abs=0.5)  # arrival + 7 s hold
    assert reached[2][1] == pytest.approx(takeoff + leg + 10.0, abs=0.6)  # loiter 3 s more
    assert nav.mode is Mode.HOLD and nav.in_air


def test_set_current_ends_a_dwell_early_and_upload_replaces_mission():
    home = frames.Home()
    nav = Navigator(home)
    nav.replace_mission([_wp(0, home, 0, 0, 3.0, hold=1000.0), _wp(1, home, 5, 0, 3.0)])
    nav.arm()
    nav.start_mission()
    t = run_nav(nav, lambda n: n._phase == "hold")
    t_hold = t
    for _ in range(100):  # the hold persists ...
        nav.step(t, DT)
        t += DT
    assert nav.seq == 0 and nav._phase == "hold"
    assert nav.set_current(1)  # ... until the client advances
    t = run_nav(nav, lambda n: n.complete, t)
    assert t - t_hold < 5 + 10
    assert np.allclose(nav.pos, [5, 0, 3], atol=0.2)
    nav.replace_mission([_wp(0, home, -5, 0, 3.0)])  # not in mission mode: waits for a start
    assert nav.mission_state == 2  # NOT_STARTED
    assert not nav.set_current(5)


def test_rtl_returns_home_lands_and_disarms():
    home = frames.Home()
    nav = Navigator(home, params=NavParams(rtl_alt=6.0))
    nav.arm()
    nav.takeoff(3.0)
    nav.goto(np.array([20.0, 10.0, 3.0]), None)
    t = run_nav(nav, lambda n: motion.arrived(n.pos, n.vel, n.target))
    max_z = 0.0
    assert nav.rtl()
    while nav.armed:
        nav.step(t, DT)
        t += DT
        max_z = max(max_z, nav.pos[2])
        assert t < 200
    assert max_z == pytest.approx(6.0, abs=0.15)  # climbs to the RTL altitude (small overshoot on the turn)
    assert np.allclose(nav.pos, 0, atol=0.2) and nav.landed


@settings(max_examples=40, deadline=None)
@given(st.tuples(st.floats(-60, 60), st.floats(-60, 60), st.floats(0, 20)), st.floats(0.5, 8), st.floats(0.5, 4))
def test_any_leg_respects_limits_and_arrives(target, vmax, amax):
    lim = motion.MotionLimits(max_speed_xy=vmax, max_speed_up=2.0, max_speed_down=1.0, max_accel=amax)
    t, pos, speeds, accels, _ = fly(list(target), lim, max_t=400)
    assert np.max(np.linalg.norm(speeds[:, :2], axis=1)) <= vmax + 1e-6
    assert np.max(speeds[:, 2]) <= 2.0 + 1e-6 and np.min(speeds[:, 2]) >= -1.0 - 1e-6
    assert np.max(accels) <= amax + 1e-6
    d = np.linalg.norm(target)
    # never faster than the largest speed the horizontal and vertical limits allow together
    assert t >= d / math.hypot(vmax, 2.0) - 1e-6


def test_via_points_are_passed_without_stopping():
    home = frames.Home()
    nav = Navigator(home, motion.MotionLimits(max_speed_xy=3.0, max_accel=2.0), NavParams(pass_radius=0.5))
    nav.pos[2] = 3.0
    nav.landed = False
    nav.replace_mission([_wp(0, home, 10, 0, 3.0), _wp(1, home, 10, 10, 3.0), _wp(2, home, 10, 10, 3.0, hold=1.0)])
    nav.arm()
    nav.start_mission()
    t, min_speed_at_corner = 0.0, None
    while nav.seq < 2:
        nav.step(t, DT)
        t += DT
        if nav.seq == 1 and min_speed_at_corner is None:
            min_speed_at_corner = float(np.linalg.norm(nav.vel))
        assert t < 60
    assert min_speed_at_corner > 0.5  # it did not stop at the via point
    # faster than two separate rest-to-rest legs
    assert t < 2 * motion.straight_leg_time(10.0, 3.0, 2.0)
