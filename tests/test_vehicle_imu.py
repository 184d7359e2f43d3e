"""HIGHRES_IMU: analytic cases of the IMU model (specific force, body rates, field, barometer), the sample grid
over the 50 ms steps, and the stream over real UDP at the rate SET_MESSAGE_INTERVAL asks; its sensor noise
(PX4 SITL's noise densities) measured on a standing vehicle against the chi-square bound."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as M
from scipy import stats

from radseek.coordinates import Home
from vehicle_sim.harness import Gcs, VehicleThread, free_udp_port, thread_config
from vehicle_sim.imu import (
    ACCEL_NOISE_DENSITY,
    GRAVITY,
    GYRO_NOISE_DENSITY,
    IMU_HZ,
    MAX_WALL_HZ,
    ImuNoise,
    ImuStream,
    earth_field_ned,
    isa,
)

HOME = Home(47.397742, 8.545594, 488.0)


def _one(stream: ImuStream, accel, yaw_enu=math.pi / 2, yaw_rate=0.0, steps=2):
    out = []
    for k in range(1, steps + 1):
        out = stream.step(k * 0.05, 0.05, np.array(accel, dtype=float), yaw_enu, yaw_rate, HOME.alt_m, 0.0)
    return out[-1]


def test_at_rest_the_accelerometer_reads_minus_g_and_the_gyro_nothing():
    s = ImuStream(HOME, speedup=1.0)
    s.set_interval(5000)
    m = _one(s, [0, 0, 0])
    assert (m.xacc, m.yacc) == pytest.approx((0, 0), abs=1e-12) and m.zacc == pytest.approx(-GRAVITY)
    assert (m.xgyro, m.ygyro, m.zgyro) == pytest.approx((0, 0, 0), abs=1e-12)
    # facing north: the field's north component on x, none on y, down on z
    field = earth_field_ned(HOME)
    assert (m.xmag, m.ymag, m.zmag) == pytest.approx(tuple(field), abs=1e-9)
    assert 0.1 < field[0] < 0.3 and 0.3 < field[2] < 0.6  # mid-northern latitudes: ~0.2 G north, ~0.4 G down
    assert m.abs_pressure == pytest.approx(isa(HOME.alt_m)[0]) and 950 < m.abs_pressure < 960  # ISA at 488 m
    assert m.pressure_alt == pytest.approx(HOME.alt_m)


def test_climbing_and_accelerating_east_the_specific_force():
    s = ImuStream(HOME, speedup=1.0)
    s.set_interval(5000)
    up = _one(s, [0, 0, 2.0])
    assert up.zacc == pytest.approx(-(GRAVITY + 2.0))
    s = ImuStream(HOME, speedup=1.0)
    s.set_interval(5000)
    east = _one(s, [1.0, 0, 0])  # facing north, accelerating east: rolled right, the thrust along -z body
    assert math.hypot(east.xacc, east.yacc, east.zacc) == pytest.approx(math.hypot(1.0, GRAVITY))
    assert abs(east.yacc) < 1e-9 and abs(east.xacc) < 1e-9


def test_yawing_the_gyro_reads_the_yaw_rate_clockwise_positive():
    s = ImuStream(HOME, speedup=1.0)
    s.set_interval(5000)
    m = _one(s, [0, 0, 0], yaw_rate=0.5)  # ENU counter-clockwise
    assert m.zgyro == pytest.approx(-0.5) and abs(m.xgyro) < 1e-12 and abs(m.ygyro) < 1e-12


def test_samples_spread_over_each_step_at_the_requested_rate():
    s = ImuStream(HOME, speedup=1.0)
    s.set_interval(5000)  # 200 Hz: ten samples in a 50 ms step
    stamps = [m.time_usec for k in range(1, 5) for m in s.step(k * 0.05, 0.05, np.zeros(3), 0.0, 0.0, 0.0, 0.0)]
    assert stamps == list(range(5000, 200_001, 5000))
    fast = ImuStream(HOME, speedup=10.0)
    fast.set_interval(5000)  # at 10x: capped at MAX_WALL_HZ messages a wall second
    assert fast.rate_hz == pytest.approx(MAX_WALL_HZ / 10)
    stamps = [m.time_usec for k in range(1, 21) for m in fast.step(k * 0.05, 0.05, np.zeros(3), 0.0, 0.0, 0.0, 0.0)]
    assert np.diff(stamps).tolist() == [40_000] * (len(stamps) - 1) and len(stamps) == 25
    s.set_interval(-1)
    assert s.step(0.25, 0.05, np.zeros(3), 0.0, 0.0, 0.0, 0.0) == []


@pytest.mark.io
def test_the_vehicle_streams_highres_imu_once_asked():
    gcs_port = free_udp_port()
    with VehicleThread(thread_config(free_udp_port(), gcs_port)) as vehicle, Gcs(gcs_port) as gcs:
        gcs.wait_vehicle()
        gcs.poll(0.2)
        assert not any(m.get_type() == "HIGHRES_IMU" for m in gcs.received)  # off until asked
        assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HIGHRES_IMU, 5000) == 0
        samples = []
        deadline = time.monotonic() + 30  # bounds the wait only
        while len(samples) < 100 and time.monotonic() < deadline:
            samples += [m for m in gcs.poll() if m.get_type() == "HIGHRES_IMU"]
        assert len(samples) >= 100
        assert np.diff([m.time_usec for m in samples]).tolist() == [5000] * (len(samples) - 1)  # 200 Hz, sim time
        sigma = ACCEL_NOISE_DENSITY * math.sqrt(IMU_HZ)
        assert all(abs(m.zacc + GRAVITY) < 6 * sigma and m.fields_updated == 0x1FFF for m in samples)
        assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HIGHRES_IMU, -1) == 0
        assert vehicle.imu.rate_hz == 0


#: a bound missed once in 1e6 seeds of a correct model, per check
P_MISS = 1e-6


def _chi2_bounds(dof: int) -> tuple[float, float]:
    return stats.chi2.ppf(P_MISS / 2, dof), stats.chi2.isf(P_MISS / 2, dof)


@pytest.mark.io
def test_a_standing_vehicles_imu_noise_has_px4_sitls_density():
    """Issue 33 (d): 600 HIGHRES_IMU samples of a standing vehicle over real UDP (the truth there: (0, 0, -g) and
    no rotation). Per sensor the sum of squared deviations on its three axes over the per-sample variance
    (density^2 * IMU_HZ) is chi-square with 1800 degrees of freedom: inside its two-sided 1e-6 bounds (the same
    readings for a density 15 % off are outside them); each axis's mean is zero within 5 standard errors and
    successive samples are uncorrelated."""
    n = 600
    gcs_port = free_udp_port()
    with VehicleThread(thread_config(free_udp_port(), gcs_port, seed=11)) as vehicle, Gcs(gcs_port) as gcs:
        gcs.wait_vehicle()
        assert vehicle.imu.noise is not None  # the vehicle's default: PX4 SITL's noise
        assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HIGHRES_IMU, 5000) == 0
        samples = []
        deadline = time.monotonic() + 60  # bounds the wait only
        while len(samples) < n and time.monotonic() < deadline:
            samples += [m for m in gcs.poll() if m.get_type() == "HIGHRES_IMU"]
    assert len(samples) >= n
    samples = samples[:n]
    acc = np.array([[m.xacc, m.yacc, m.zacc + GRAVITY] for m in samples])
    gyro = np.array([[m.xgyro, m.ygyro, m.zgyro] for m in samples])
    lo, hi = _chi2_bounds(3 * n)
    for name, x, density in (("accelerometer", acc, ACCEL_NOISE_DENSITY), ("gyroscope", gyro, GYRO_NOISE_DENSITY)):
        sigma = density * math.sqrt(IMU_HZ)
        chi2 = (x ** 2).sum() / sigma ** 2
        assert lo < chi2 < hi, (name, chi2, lo, hi)
        for off in (0.85, 1.15):  # the bound can fail: a density 15 % off is outside it
            assert not lo < chi2 / off ** 2 < hi, (name, off, chi2 / off ** 2, lo, hi)
        assert np.all(np.abs(x.mean(axis=0)) < 5 * sigma / math.sqrt(n)), (name, x.mean(axis=0))
        lag1 = (x[1:] * x[:-1]).sum(axis=0) / (x ** 2).sum(axis=0)  # ~ N(0, 1/n) for white noise
        assert np.all(np.abs(lag1) < 5 / math.sqrt(n)), (name, lag1)


def test_the_noise_follows_the_seed_and_is_off_when_asked():
    """The same seed draws the same readings (and the stream and the present-state samples draw apart); a
    stream without noise reads the truth exactly."""
    def readings(noise):
        s = ImuStream(HOME, speedup=1.0, noise=noise)
        s.set_interval(5000)
        return [(m.xacc, m.zgyro) for k in range(1, 5) for m in s.step(k * 0.05, 0.05, np.zeros(3), 0.0, 0.0, 0.0, 0.0)]

    a, b = readings(ImuNoise.seeded(4, 0)), readings(ImuNoise.seeded(4, 0))
    assert a == b and len(set(a)) == len(a)
    assert readings(ImuNoise.seeded(4, 1)) != a and readings(ImuNoise.seeded(5, 0)) != a
    assert set(readings(None)) == {(0.0, 0.0)}
    with pytest.raises(ValueError, match="densities must be >= 0"):
        ImuNoise(np.random.default_rng(0), accel_density=-1.0)
