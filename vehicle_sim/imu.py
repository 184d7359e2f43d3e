"""HIGHRES_IMU from the simulated motion, at the rate SET_MESSAGE_INTERVAL asks (MAVSDK's ``set_rate_imu``).

What an IMU strapped to the multicopter would read, noise-free:

- accelerometer (body FRD, m/s^2): the specific force, the kinematic acceleration minus gravity (NED: a - (0, 0,
  g)), rotated into the body frame of the attitude ATTITUDE reports (tilt from the horizontal acceleration, yaw):
  (0, 0, -g) at rest, -g - climb acceleration on z when climbing;
- gyroscope (body FRD, rad/s): the body rates of that attitude (Euler-angle rates turned into p, q, r): the yaw
  rate on z in level flight, clockwise positive;
- magnetometer (gauss): a centred-dipole Earth field at the home (0.305 G at the geomagnetic equator, pole at
  80.7 N 72.7 W; declination not modelled), rotated into the body;
- barometer: ISA pressure (hPa) and temperature at the altitude AMSL, ``pressure_alt`` that altitude.

The vehicle steps every ``dt`` sim seconds (50 ms): a stream faster than the steps gets several samples per step,
at the sample instants k / rate that fall in the step, each with its own ``time_usec``; within a step the
acceleration is constant (the kinematic model's) and the yaw and tilt are interpolated linearly. The rate achieved
is min(requested, ``MAX_WALL_HZ`` / speed-up) samples per simulated second: 200 Hz at 1x, 25 Hz of simulated
time at 10x (250 messages per wall second), so a sped-up simulation does not flood the link.
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import common as M

from radseek.coordinates import Home, yaw_enu_to_ned

GRAVITY = 9.80665
MAX_WALL_HZ = 250.0  # HIGHRES_IMU messages per wall second at most
DIPOLE_G = 0.305  # gauss at the geomagnetic equator
POLE_LAT, POLE_LON = math.radians(80.7), math.radians(-72.7)
FIELDS_ALL = 0x1FFF  # acc, gyro, mag (x, y, z), abs/diff pressure, pressure altitude, temperature


def tilt(accel_enu: np.ndarray, yaw_ned: float) -> tuple[float, float]:
    """Roll and pitch (rad) of a multicopter accelerating horizontally by ``accel_enu``: small-angle model,
    the one ATTITUDE reports (``telemetry._tilt``)."""
    a_n, a_e = float(accel_enu[1]), float(accel_enu[0])
    fwd = a_n * math.cos(yaw_ned) + a_e * math.sin(yaw_ned)
    right = -a_n * math.sin(yaw_ned) + a_e * math.cos(yaw_ned)
    return math.atan2(right, GRAVITY), -math.atan2(fwd, GRAVITY)


def body_from_ned(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rotation matrix taking NED vectors into the body FRD frame (ZYX Euler angles)."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw),
                              math.sin(yaw))
    return np.array([
        [cp * cy, cp * sy, -sp],
        [sr * sp * cy - cr * sy, sr * sp * sy + cr * cy, sr * cp],
        [cr * sp * cy + sr * sy, cr * sp * sy - sr * cy, cr * cp],
    ])


def earth_field_ned(home: Home) -> np.ndarray:
    """Centred-dipole field (gauss, NED) at the home, declination ignored."""
    lat, lon = math.radians(home.lat_deg), math.radians(home.lon_deg)
    s = math.sin(lat) * math.sin(POLE_LAT) + math.cos(lat) * math.cos(POLE_LAT) * math.cos(lon - POLE_LON)
    mlat = math.asin(max(-1.0, min(1.0, s)))
    return np.array([DIPOLE_G * math.cos(mlat), 0.0, 2 * DIPOLE_G * math.sin(mlat)])


def isa(alt_m: float) -> tuple[float, float]:
    """ISA pressure (hPa) and temperature (degC) at ``alt_m`` AMSL (troposphere)."""
    return 1013.25 * (1 - 2.25577e-5 * alt_m) ** 5.25588, 15.0 - 0.0065 * alt_m


class ImuStream:
    """The HIGHRES_IMU stream: its rate, and the samples of each sim step."""

    def __init__(self, home: Home, speedup: float):
        self.home, self.speedup = home, speedup
        self.requested_hz = 0.0  # off until asked for (PX4 does not stream it to a GCS by default)
        self._mag = earth_field_ned(home)
        self._last_tilt: tuple[float, float] | None = None

    @property
    def rate_hz(self) -> float:
        """Samples per simulated second actually sent."""
        return min(self.requested_hz, MAX_WALL_HZ / self.speedup)

    def set_interval(self, interval_us: float) -> None:
        """MAVLink semantics: -1 off, 0 the default (off), > 0 the interval."""
        self.requested_hz = 1e6 / interval_us if interval_us > 0 else 0.0

    def step(self, t: float, dt: float, accel_enu: np.ndarray, yaw_enu: float, yaw_rate_enu: float,
             alt_amsl: float, climb_rate: float, tilt_flown: tuple[float, float] | None = None) -> list:
        """The samples whose instants fall in (t - dt, t], for the step that ended at sim time ``t``;
        ``tilt_flown`` the roll and pitch when the vehicle flies an attitude (else the tilt of the acceleration)."""
        yaw1 = yaw_enu_to_ned(yaw_enu)
        t1 = tilt(accel_enu, yaw1) if tilt_flown is None else tuple(tilt_flown)
        t0 = self._last_tilt if self._last_tilt is not None else t1
        self._last_tilt = t1
        hz = self.rate_hz
        if hz <= 0:
            return []
        k0, k1 = math.floor((t - dt) * hz + 1e-9) + 1, math.floor(t * hz + 1e-9)
        rates = ((t1[0] - t0[0]) / dt, (t1[1] - t0[1]) / dt, -yaw_rate_enu)  # roll, pitch, yaw (NED) rates
        out = []
        for k in range(k0, k1 + 1):
            back = t - k / hz  # s before the step's end, in [0, dt)
            w = 1.0 - back / dt  # weight of the step's end state
            att = (t0[0] + w * (t1[0] - t0[0]), t0[1] + w * (t1[1] - t0[1]), yaw1 - back * rates[2])
            out.append(self.sample(k / hz, att, rates, accel_enu, alt_amsl - back * climb_rate))
        return out

    def sample(self, ts: float, att: tuple[float, float, float], rates: tuple[float, float, float],
               accel_enu: np.ndarray, alt_amsl: float):
        """One HIGHRES_IMU at sim time ``ts`` for attitude ``att`` (roll, pitch, yaw NED, rad), its Euler rates
        (rad/s), the acceleration (ENU m/s^2) and the altitude AMSL (m)."""
        roll, pitch, yaw = att
        r = body_from_ned(roll, pitch, yaw)
        a_ned = np.array([accel_enu[1], accel_enu[0], -accel_enu[2]])
        acc = r @ (a_ned - np.array([0.0, 0.0, GRAVITY]))
        droll, dpitch, dyaw = rates
        p = droll - dyaw * math.sin(pitch)
        q = dpitch * math.cos(roll) + dyaw * math.sin(roll) * math.cos(pitch)
        rr = -dpitch * math.sin(roll) + dyaw * math.cos(roll) * math.cos(pitch)
        mag = r @ self._mag
        press, temp = isa(alt_amsl)
        return M.MAVLink_highres_imu_message(int(round(ts * 1e6)), *map(float, acc), p, q, rr, *map(float, mag),
                                             press, 0.0, alt_amsl, temp, FIELDS_ALL, 0)
