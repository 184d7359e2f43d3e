"""HIGHRES_IMU from the simulated motion, at the rate SET_MESSAGE_INTERVAL asks (MAVSDK's ``set_rate_imu``).

What an IMU strapped to the multicopter would read (noise-free, plus the white noise of :class:`ImuNoise`):

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

Sensor noise (:class:`ImuNoise`): white Gaussian noise on each accelerometer and gyroscope axis with PX4 SITL's
default noise densities, those of its default vehicle (PX4-SITL_gazebo-classic ``models/iris/iris.sdf.jinja``,
``rotors_gazebo_imu_plugin``: ``accelerometerNoiseDensity`` 0.00186 m/s^2/sqrt(Hz), ``gyroscopeNoiseDensity``
0.00018665 rad/s/sqrt(Hz)), discretised as that plugin does (``src/gazebo_imu_plugin.cpp``, ``addNoise``: standard
deviation density / sqrt(dt), an integrating sampler over the IMU's sample interval dt). Every value sent or
logged is one sample of an IMU running at ``IMU_HZ`` (gazebo-classic's 4 ms physics step, at which its IMU plugin
publishes; a HIGHRES_IMU or sensor_combined carries the latest sample, as PX4's do). The plugin's bias processes
(turn-on bias, bias random walk) are not modelled. The noise is drawn from the vehicle's seed: the same seed, the
same readings.
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
ACCEL_NOISE_DENSITY = 0.00186  # m/s^2/sqrt(Hz), PX4 SITL's iris (accelerometerNoiseDensity)
GYRO_NOISE_DENSITY = 0.00018665  # rad/s/sqrt(Hz), PX4 SITL's iris (gyroscopeNoiseDensity)
IMU_HZ = 250.0  # the simulated IMU's own sample rate (gazebo-classic: one sample per 4 ms physics step)


class ImuNoise:
    """White accelerometer and gyroscope noise of an IMU sampled at ``rate_hz``: per axis and sample,
    N(0, (density * sqrt(rate_hz))^2), drawn from ``rng``."""

    def __init__(self, rng: np.random.Generator, accel_density: float = ACCEL_NOISE_DENSITY,
                 gyro_density: float = GYRO_NOISE_DENSITY, rate_hz: float = IMU_HZ):
        if not (accel_density >= 0 and gyro_density >= 0 and rate_hz > 0):
            raise ValueError(f"IMU noise densities must be >= 0 and its rate > 0, got {accel_density!r}, "
                             f"{gyro_density!r}, {rate_hz!r}")
        self.rng = rng
        self.accel_sigma = accel_density * math.sqrt(rate_hz)  # m/s^2 per sample
        self.gyro_sigma = gyro_density * math.sqrt(rate_hz)  # rad/s per sample

    @classmethod
    def seeded(cls, seed: int, stream: int, **kw) -> ImuNoise:
        """Noise drawn from ``seed`` (the vehicle's), one independent ``stream`` per consumer of samples."""
        return cls(np.random.default_rng([seed, 0x1AE, stream]), **kw)

    def draw(self) -> tuple[np.ndarray, np.ndarray]:
        """One sample's accelerometer (m/s^2) and gyroscope (rad/s) noise, body axes."""
        z = self.rng.standard_normal(6)
        return z[:3] * self.accel_sigma, z[3:] * self.gyro_sigma


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

    def __init__(self, home: Home, speedup: float, noise: ImuNoise | None = None,
                 noise_now: ImuNoise | None = None):
        """``noise`` for the stream's samples, ``noise_now`` for the vehicle's samples of the present state (a
        ULog record, a REQUEST_MESSAGE: :meth:`sample` with it): two generators, so a request at a wall-clock
        moment leaves the stream's readings as the seed makes them. None: noise-free."""
        self.home, self.speedup = home, speedup
        self.noise, self.noise_now = noise, noise_now
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
            out.append(self.sample(k / hz, att, rates, accel_enu, alt_amsl - back * climb_rate, self.noise))
        return out

    def sample(self, ts: float, att: tuple[float, float, float], rates: tuple[float, float, float],
               accel_enu: np.ndarray, alt_amsl: float, noise: ImuNoise | None = None):
        """One HIGHRES_IMU at sim time ``ts`` for attitude ``att`` (roll, pitch, yaw NED, rad), its Euler rates
        (rad/s), the acceleration (ENU m/s^2) and the altitude AMSL (m), with ``noise`` (None: noise-free)."""
        roll, pitch, yaw = att
        r = body_from_ned(roll, pitch, yaw)
        a_ned = np.array([accel_enu[1], accel_enu[0], -accel_enu[2]])
        acc = r @ (a_ned - np.array([0.0, 0.0, GRAVITY]))
        droll, dpitch, dyaw = rates
        p = droll - dyaw * math.sin(pitch)
        q = dpitch * math.cos(roll) + dyaw * math.sin(roll) * math.cos(pitch)
        rr = -dpitch * math.sin(roll) + dyaw * math.cos(roll) * math.cos(pitch)
        gyro = np.array([p, q, rr])
        if noise is not None:
            n_acc, n_gyro = noise.draw()
            acc, gyro = acc + n_acc, gyro + n_gyro
        mag = r @ self._mag
        press, temp = isa(alt_amsl)
        return M.MAVLink_highres_imu_message(int(round(ts * 1e6)), *map(float, acc), *map(float, gyro),
                                             *map(float, mag), press, 0.0, alt_amsl, temp, FIELDS_ALL, 0)
