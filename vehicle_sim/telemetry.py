"""Telemetry: MAVLink messages built from a vehicle snapshot, and their emission schedule.

Everything sent is the vehicle's *estimate* (GPS-denied odometry), never the truth. Positions go out
as NED / WGS-84 (``frames``). Rates are in sim Hz like SITL, capped at ``max_wall_hz`` per message so
a fast simulation does not flood a ground station.

GPS-denied, honestly: GPS_RAW_INT reports the receiver as connected without a fix (fix_type NO_FIX,
0 satellites, position and accuracies unknown), so MAVSDK's ``gps_info`` yields ``NO_FIX``. SYS_STATUS
still marks the GPS sensor bit healthy: MAVSDK (telemetry_impl.cpp, ``process_sys_status``) reads that
one bit as "global position estimate OK" and nothing else, and the vehicle does have a global estimate
(VIO anchored at the known home, with its variance in ODOMETRY); clearing it would make every MAVSDK
client wait forever for ``is_global_position_ok``. VISION_POSITION is marked present and healthy too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as M

from radseek.coordinates import Home, enu_to_geodetic, enu_to_ned, yaw_enu_to_ned
from vehicle_sim.imu import tilt
from vehicle_sim.navigator import MANUAL_MODES, Mode, px4_custom_mode

CAPABILITIES = (M.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT | M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                | M.MAV_PROTOCOL_CAPABILITY_MISSION_INT | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | M.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | M.MAV_PROTOCOL_CAPABILITY_FTP)
FLIGHT_SW_VERSION = (1 << 24) | (14 << 16) | (0 << 8) | 255  # announces PX4-compatible 1.14.0 release
GIT_HASH = b"radseek\x00"  # flight_custom_version: where PX4 puts the first 8 bytes of its git hash
UID = 0x5241445345454B  # "RADSEEK"
SENSORS = (M.MAV_SYS_STATUS_SENSOR_3D_GYRO | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL | M.MAV_SYS_STATUS_SENSOR_3D_MAG
           | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE | M.MAV_SYS_STATUS_SENSOR_GPS
           | M.MAV_SYS_STATUS_SENSOR_VISION_POSITION | M.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
           | M.MAV_SYS_STATUS_AHRS | M.MAV_SYS_STATUS_SENSOR_BATTERY | M.MAV_SYS_STATUS_PREARM_CHECK
           | M.MAV_SYS_STATUS_GEOFENCE)

# message name -> default rate in sim Hz
DEFAULT_RATES: dict[str, float] = {
    "HEARTBEAT": 1.0, "SYS_STATUS": 1.0, "BATTERY_STATUS": 1.0, "GLOBAL_POSITION_INT": 10.0,
    "LOCAL_POSITION_NED": 10.0, "ATTITUDE": 10.0, "ODOMETRY": 10.0, "EXTENDED_SYS_STATE": 2.0,
    "MISSION_CURRENT": 1.0, "HOME_POSITION": 0.5, "GPS_RAW_INT": 1.0,
}
MSG_IDS: dict[int, str] = {getattr(M, f"MAVLINK_MSG_ID_{n}"): n for n in (*DEFAULT_RATES, "AUTOPILOT_VERSION")}


@dataclass
class Snapshot:
    """What telemetry needs to know about the vehicle at sim time ``t`` (estimated ENU state)."""

    t: float
    pos: np.ndarray
    vel: np.ndarray
    accel: np.ndarray
    yaw: float
    yaw_rate: float
    var: np.ndarray  # (x, y, z, yaw) variances
    armed: bool
    landed: bool
    landed_state: int  # MAV_LANDED_STATE
    mode: Mode
    battery: float  # remaining fraction
    voltage: float
    home: Home
    mission_seq: int
    mission_total: int
    mission_state: int
    failsafe: bool
    reset_counter: int = 0
    failures: frozenset = frozenset()  # units turned off by failure injection ("gps", "battery")
    tilt: tuple[float, float] | None = None  # roll, pitch flown (attitude offboard); else from the acceleration


def _ms(t: float) -> int:
    return int(t * 1000) & 0xFFFFFFFF


def _tilt(s: Snapshot) -> tuple[float, float]:
    """Roll and pitch (NED body FRD) of a multicopter accelerating by ``accel``: small-angle model."""
    return s.tilt if s.tilt is not None else tilt(s.accel, yaw_enu_to_ned(s.yaw))


def quaternion(roll: float, pitch: float, yaw: float) -> list[float]:
    """Body FRD -> NED rotation (ZYX Euler angles, rad) as (w, x, y, z): ATTITUDE_QUATERNION's and ULog's q."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy]


def heartbeat(s: Snapshot):
    base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | M.MAV_MODE_FLAG_STABILIZE_ENABLED | M.MAV_MODE_FLAG_GUIDED_ENABLED
    if s.mode in MANUAL_MODES:
        base |= M.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
    else:
        base |= M.MAV_MODE_FLAG_AUTO_ENABLED
    if s.armed:
        base |= M.MAV_MODE_FLAG_SAFETY_ARMED
    status = M.MAV_STATE_CRITICAL if s.failsafe else (M.MAV_STATE_ACTIVE if s.armed else M.MAV_STATE_STANDBY)
    return M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, base, px4_custom_mode(s.mode),
                                       status, 3)


def sys_status(s: Snapshot):
    sensors = SENSORS & ~(M.MAV_SYS_STATUS_SENSOR_GPS if "gps" in s.failures else 0)
    health = sensors & ~(M.MAV_SYS_STATUS_SENSOR_BATTERY if "battery" in s.failures else 0)
    if "battery" in s.failures:  # monitor off: MAVLink's unknown voltage, current and charge
        return M.MAVLink_sys_status_message(sensors, sensors, health, 200, 65535, -1, -1, 0, 0, 0, 0, 0, 0)
    return M.MAVLink_sys_status_message(sensors, sensors, health, 200, int(s.voltage * 1000), 1000 if s.armed else 50,
                                        int(round(s.battery * 100)), 0, 0, 0, 0, 0, 0)


def battery_status(s: Snapshot):
    if "battery" in s.failures:  # monitor off: no cell voltages, current or charge known
        return M.MAVLink_battery_status_message(0, M.MAV_BATTERY_FUNCTION_ALL, M.MAV_BATTERY_TYPE_LIPO, 32767,
                                                [65535] * 10, -1, -1, -1, -1, 0, M.MAV_BATTERY_CHARGE_STATE_UNHEALTHY,
                                                [0, 0, 0, 0], 0, 0)
    cells = int(round(s.voltage / 4.0)) or 1
    per_cell = int(s.voltage / cells * 1000)
    volts = [per_cell] * cells + [65535] * (10 - cells)
    return M.MAVLink_battery_status_message(0, M.MAV_BATTERY_FUNCTION_ALL, M.MAV_BATTERY_TYPE_LIPO, 2500, volts,
                                            1000 if s.armed else 50, -1, -1, int(round(s.battery * 100)), 0,
                                            M.MAV_BATTERY_CHARGE_STATE_OK, [0, 0, 0, 0], 0, 0)


def global_position_int(s: Snapshot):
    lat, lon, alt = enu_to_geodetic(s.home, s.pos)
    v = enu_to_ned(s.vel)
    hdg = int(round(math.degrees(yaw_enu_to_ned(s.yaw)) % 360 * 100)) % 36000
    return M.MAVLink_global_position_int_message(_ms(s.t), int(round(lat * 1e7)), int(round(lon * 1e7)),
                                                 int(round(alt * 1000)), int(round(s.pos[2] * 1000)),
                                                 *(int(round(c * 100)) for c in v), hdg)


def local_position_ned(s: Snapshot):
    p, v = enu_to_ned(s.pos), enu_to_ned(s.vel)
    return M.MAVLink_local_position_ned_message(_ms(s.t), *map(float, p), *map(float, v))


def attitude(s: Snapshot):
    roll, pitch = _tilt(s)
    return M.MAVLink_attitude_message(_ms(s.t), roll, pitch, yaw_enu_to_ned(s.yaw), 0.0, 0.0, -s.yaw_rate)


def odometry(s: Snapshot):
    """Estimated pose with its covariance (upper triangle, row-major, of x y z roll pitch yaw)."""
    roll, pitch = _tilt(s)
    yaw = yaw_enu_to_ned(s.yaw)
    p = enu_to_ned(s.pos)
    v_ned = enu_to_ned(s.vel)
    c, sn = math.cos(yaw), math.sin(yaw)  # body FRD velocity (small-angle: yaw rotation only)
    v_body = [c * v_ned[0] + sn * v_ned[1], -sn * v_ned[0] + c * v_ned[1], v_ned[2]]
    cov = [0.0] * 21
    cov[0], cov[6], cov[11] = float(s.var[1]), float(s.var[0]), float(s.var[2])  # NED: north var = ENU y var
    cov[15] = cov[18] = 1e-4
    cov[20] = float(s.var[3])
    vel_cov = [math.nan] + [0.0] * 20  # unknown
    quality = max(0, min(100, int(100 - 100 * math.sqrt(float(s.var[0] + s.var[1])))))
    return M.MAVLink_odometry_message(int(s.t * 1e6), M.MAV_FRAME_LOCAL_NED, M.MAV_FRAME_BODY_FRD,
                                      *map(float, p), quaternion(roll, pitch, yaw), *map(float, v_body),
                                      0.0, 0.0, -s.yaw_rate, cov, vel_cov, s.reset_counter,
                                      M.MAV_ESTIMATOR_TYPE_VIO, quality)


def gps_raw_int(s: Snapshot):
    """The GPS receiver as it is in a GPS-denied flight: connected, no fix, nothing known."""
    unknown16 = 65535
    fix = M.GPS_FIX_TYPE_NO_GPS if "gps" in s.failures else M.GPS_FIX_TYPE_NO_FIX  # injected off: no receiver
    return M.MAVLink_gps_raw_int_message(int(s.t * 1e6), fix, 0, 0, 0, unknown16, unknown16,
                                         unknown16, unknown16, 0, 0, 0, 0, 0, 0, 0)


def home_position(s: Snapshot):
    h = s.home
    return M.MAVLink_home_position_message(int(round(h.lat_deg * 1e7)), int(round(h.lon_deg * 1e7)),
                                           int(round(h.alt_m * 1000)), 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0],
                                           0.0, 0.0, 0.0, int(s.t * 1e6))


def extended_sys_state(s: Snapshot):
    return M.MAVLink_extended_sys_state_message(M.MAV_VTOL_STATE_UNDEFINED, s.landed_state)


def mission_current(s: Snapshot):
    mode = 1 if s.mode is Mode.MISSION else 0
    return M.MAVLink_mission_current_message(s.mission_seq, s.mission_total, s.mission_state, mode)


def autopilot_version(s: Snapshot):
    return M.MAVLink_autopilot_version_message(CAPABILITIES, FLIGHT_SW_VERSION, 0, 0, 0, list(GIT_HASH), [0] * 8,
                                               [0] * 8, 0, 0, UID, [0] * 18)


BUILDERS = {
    "HEARTBEAT": heartbeat, "SYS_STATUS": sys_status, "BATTERY_STATUS": battery_status,
    "GLOBAL_POSITION_INT": global_position_int, "LOCAL_POSITION_NED": local_position_ned, "ATTITUDE": attitude,
    "ODOMETRY": odometry, "HOME_POSITION": home_position, "EXTENDED_SYS_STATE": extended_sys_state,
    "MISSION_CURRENT": mission_current, "AUTOPILOT_VERSION": autopilot_version, "GPS_RAW_INT": gps_raw_int,
}


def statustext(text: str, severity: int, text_id: int = 0) -> list:
    """STATUSTEXT message(s): texts longer than 50 characters are sent in chunks sharing an id."""
    raw = text.encode("utf-8", "replace")
    if len(raw) <= 50:
        return [M.MAVLink_statustext_message(severity, raw, 0, 0)]
    chunks = [raw[k:k + 50] for k in range(0, len(raw), 50)]
    return [M.MAVLink_statustext_message(severity, c, text_id, k) for k, c in enumerate(chunks)]


class Scheduler:
    """Which periodic messages are due at sim time ``t``; intervals settable by SET_MESSAGE_INTERVAL."""

    def __init__(self, speedup: float, max_wall_hz: float = 20.0, rates: dict[str, float] | None = None):
        self.speedup, self.max_wall_hz = speedup, max_wall_hz
        self.rates = dict(DEFAULT_RATES if rates is None else rates)
        self._next: dict[str, float] = {}

    def interval(self, name: str) -> float | None:
        hz = self.rates.get(name, 0.0)
        if hz <= 0:
            return None
        return max(1.0 / hz, self.speedup / self.max_wall_hz)

    def set_interval(self, name: str, interval_us: float) -> None:
        """MAVLink semantics: -1 disables, 0 restores the default, > 0 sets the interval (us)."""
        if interval_us < 0:
            self.rates[name] = 0.0
        elif interval_us == 0:
            self.rates[name] = DEFAULT_RATES.get(name, 0.0)
        else:
            self.rates[name] = 1e6 / interval_us
        self._next.pop(name, None)

    def due(self, t: float) -> list[str]:
        out = []
        for name in self.rates:
            iv = self.interval(name)
            if iv is None:
                continue
            nxt = self._next.get(name)
            if nxt is None or t >= nxt:
                out.append(name)
                self._next[name] = t + iv if nxt is None or t - nxt > iv else nxt + iv
        return out
