"""The vehicle's ULog, as PX4's logger writes it: the uORB topics PX4 logs that the mock vehicle has, in microseconds
of simulated time since boot.

PX4 writes ``/fs/microsd/log/<date>/<time>.ulg`` from boot (SDLOG_MODE 2) and serves it as log 0 of the log
protocol; this is that file, held in memory (``vehicle_sim.ulog_log``) and served while it grows. It holds:

- info: ``sys_name`` PX4, ``ver_hw`` PX4_SITL (what Flight Review and PlotJuggler key on), ``ver_sw``,
  ``sys_os_name``, ``time_ref_utc``; the vehicle's PX4-style parameters ('P', ``float`` or ``int32_t`` as their
  MAVLink type), a change made in flight logged where it happened;
- topics, each a subset of PX4's message definition with PX4's field names, on the sim-step grid at PX4's default
  logging intervals: ``vehicle_attitude`` (50 ms; ``q`` body FRD to NED, w x y z), ``vehicle_local_position``
  (100 ms; NED m, m/s, m/s^2 from the home origin), ``sensor_combined`` (100 ms; the IMU's specific force and body
  rates, ``vehicle_sim.imu``), ``vehicle_global_position``, ``vehicle_status`` (``nav_state`` in PX4's numbering)
  and ``battery_status`` (200 ms);
- the vehicle's STATUSTEXTs as logged strings ('L', MAV_SEVERITY as the level), whole (not in 50-byte chunks).

Every message is written at the sim time it describes, so the file's timestamps never go back."""

from __future__ import annotations

import math
import time

import numpy as np

from radseek.coordinates import enu_to_geodetic, enu_to_ned, yaw_enu_to_ned
from vehicle_sim.imu import tilt
from vehicle_sim.navigator import Mode
from vehicle_sim.telemetry import Snapshot, quaternion
from vehicle_sim.ulog_log import DEFAULT_MAX_BYTES, Format, UlogWriter

# PX4's vehicle_status.nav_state numbering (msg/VehicleStatus.msg)
NAV_STATE = {Mode.ALTCTL: 1, Mode.POSCTL: 2, Mode.MISSION: 3, Mode.HOLD: 4, Mode.RTL: 5, Mode.OFFBOARD: 14,
             Mode.TAKEOFF: 17, Mode.LAND: 18, Mode.FOLLOW: 19, Mode.ORBIT: 21}
ARMING_STATE_DISARMED, ARMING_STATE_ARMED = 1, 2
VEHICLE_TYPE_ROTARY_WING = 1
BATTERY_WARNING_NONE, BATTERY_WARNING_LOW, BATTERY_WARNING_CRITICAL = 0, 1, 2

T = (("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"))
FORMATS = [
    Format("vehicle_attitude", T + (("float[4]", "q"), ("float[4]", "delta_q_reset"),
                                    ("uint8_t", "quat_reset_counter"))),
    Format("vehicle_local_position", T + (
        ("bool", "xy_valid"), ("bool", "z_valid"), ("bool", "v_xy_valid"), ("bool", "v_z_valid"),
        ("float", "x"), ("float", "y"), ("float", "z"), ("float", "vx"), ("float", "vy"), ("float", "vz"),
        ("float", "ax"), ("float", "ay"), ("float", "az"), ("float", "heading"),
        ("bool", "xy_global"), ("bool", "z_global"), ("uint64_t", "ref_timestamp"), ("double", "ref_lat"),
        ("double", "ref_lon"), ("float", "ref_alt"), ("float", "eph"), ("float", "epv"))),
    Format("sensor_combined", (("uint64_t", "timestamp"), ("float[3]", "gyro_rad"), ("uint32_t", "gyro_integral_dt"),
                               ("int32_t", "accelerometer_timestamp_relative"), ("float[3]", "accelerometer_m_s2"),
                               ("uint32_t", "accelerometer_integral_dt"))),
    Format("vehicle_global_position", T + (("double", "lat"), ("double", "lon"), ("float", "alt"), ("float", "eph"),
                                           ("float", "epv"), ("bool", "dead_reckoning"))),
    Format("vehicle_status", (("uint64_t", "timestamp"), ("uint8_t", "arming_state"), ("uint8_t", "nav_state"),
                              ("uint8_t", "vehicle_type"), ("bool", "failsafe"), ("uint8_t", "system_type"),
                              ("uint8_t", "system_id"), ("uint8_t", "component_id"))),
    Format("battery_status", (("uint64_t", "timestamp"), ("bool", "connected"), ("float", "voltage_v"),
                              ("float", "current_a"), ("float", "remaining"), ("uint8_t", "cell_count"),
                              ("uint8_t", "warning"))),
]
#: s of sim time between two records of a topic (PX4's logged_topics.cpp defaults, on the 50 ms step grid)
INTERVAL_S = {"vehicle_attitude": 0.05, "vehicle_local_position": 0.1, "sensor_combined": 0.1,
              "vehicle_global_position": 0.2, "vehicle_status": 0.2, "battery_status": 0.2}


def us(t: float) -> int:
    """Sim seconds -> the log's microseconds."""
    return int(round(t * 1e6))


class Px4Logger:
    """The ULog of one boot: ``record`` each step, ``text`` each STATUSTEXT, ``param_changed`` each change."""

    def __init__(self, params: list[tuple[str, float, bool]], sysid: int = 1, compid: int = 1,
                 cells: int = 4, low: float = 0.25, critical: float = 0.10, boot_wall_s: float | None = None,
                 max_bytes: int = DEFAULT_MAX_BYTES):
        self.boot_wall_s = time.time() if boot_wall_s is None else boot_wall_s
        self.sysid, self.compid, self.cells = sysid, compid, cells
        self.low, self.critical = low, critical  # battery fractions of PX4's BAT_LOW_THR, BAT_CRIT_THR
        w = self.writer = UlogWriter(0, max_bytes)
        for fmt in FORMATS:
            w.add_format(fmt)
        w.info("sys_name", "PX4")
        w.info("ver_hw", "PX4_SITL")
        w.info("ver_sw", "radseek-vehicle_sim")
        w.info("sys_os_name", "Linux")
        w.info("time_ref_utc", 0)
        for name, value, integer in params:
            w.param(name, value, integer)
        for fmt in FORMATS:
            w.subscribe(fmt.name)
        self._last_k = {name: -1 for name in INTERVAL_S}

    @property
    def name(self) -> str:
        """PX4's log file naming: UTC date folder, time of day."""
        return time.strftime("%Y-%m-%d/%H_%M_%S.ulg", time.gmtime(self.boot_wall_s))

    @property
    def full(self) -> bool:
        return self.writer.full

    def size(self) -> int:
        return self.writer.size()

    def read(self, offset: int, count: int) -> bytes:
        return self.writer.read(offset, count)

    def due(self, t: float) -> list[str]:
        """The topics whose logging interval has a grid point in (last record, t]."""
        out = []
        for name, every in INTERVAL_S.items():
            k = math.floor(t / every + 1e-6)
            if k > self._last_k[name]:
                self._last_k[name] = k
                out.append(name)
        return out

    def record(self, s: Snapshot, imu=None, due: list[str] | None = None) -> None:
        """Log the topics due at ``s.t`` (or those of ``due``, from ``due(s.t)``); ``imu`` the HIGHRES_IMU sample at
        that time (for sensor_combined)."""
        for name in self.due(s.t) if due is None else due:
            if name == "sensor_combined" and imu is None:
                continue
            self.writer.write(name, getattr(self, "_" + name)(s, imu))

    def text(self, t: float, severity: int, text: str) -> None:
        self.writer.log(severity, us(t), text)

    def param_changed(self, name: str, value: float, integer: bool) -> None:
        self.writer.param(name, value, integer)

    # -- one record of each topic ----------------------------------------------------------------------------
    def _vehicle_attitude(self, s: Snapshot, imu) -> dict:
        yaw = yaw_enu_to_ned(s.yaw)
        roll, pitch = s.tilt if s.tilt is not None else tilt(s.accel, yaw)
        return {"timestamp": us(s.t), "timestamp_sample": us(s.t), "q": quaternion(roll, pitch, yaw),
                "delta_q_reset": [0.0] * 4, "quat_reset_counter": 0}

    def _vehicle_local_position(self, s: Snapshot, imu) -> dict:
        p, v, a = enu_to_ned(s.pos), enu_to_ned(s.vel), enu_to_ned(s.accel)
        return {"timestamp": us(s.t), "timestamp_sample": us(s.t), "xy_valid": True, "z_valid": True,
                "v_xy_valid": True, "v_z_valid": True, "x": p[0], "y": p[1], "z": p[2], "vx": v[0], "vy": v[1],
                "vz": v[2], "ax": a[0], "ay": a[1], "az": a[2], "heading": yaw_enu_to_ned(s.yaw),
                "xy_global": True, "z_global": True, "ref_timestamp": 0, "ref_lat": s.home.lat_deg,
                "ref_lon": s.home.lon_deg, "ref_alt": s.home.alt_m, **self._errors(s)}

    def _errors(self, s: Snapshot) -> dict:
        return {"eph": math.sqrt(max(float(s.var[0]), float(s.var[1]), 0.0)),
                "epv": math.sqrt(max(float(s.var[2]), 0.0))}

    def _sensor_combined(self, s: Snapshot, imu) -> dict:
        return {"timestamp": int(imu.time_usec), "gyro_rad": [imu.xgyro, imu.ygyro, imu.zgyro],
                "gyro_integral_dt": 0, "accelerometer_timestamp_relative": 0,
                "accelerometer_m_s2": [imu.xacc, imu.yacc, imu.zacc], "accelerometer_integral_dt": 0}

    def _vehicle_global_position(self, s: Snapshot, imu) -> dict:
        lat, lon, alt = enu_to_geodetic(s.home, np.asarray(s.pos))
        return {"timestamp": us(s.t), "timestamp_sample": us(s.t), "lat": lat, "lon": lon, "alt": alt,
                **self._errors(s), "dead_reckoning": "gps" in s.failures}

    def _vehicle_status(self, s: Snapshot, imu) -> dict:
        return {"timestamp": us(s.t), "arming_state": ARMING_STATE_ARMED if s.armed else ARMING_STATE_DISARMED,
                "nav_state": NAV_STATE[s.mode], "vehicle_type": VEHICLE_TYPE_ROTARY_WING, "failsafe": s.failsafe,
                "system_type": 2, "system_id": self.sysid, "component_id": self.compid}  # 2: MAV_TYPE_QUADROTOR

    def _battery_status(self, s: Snapshot, imu) -> dict:
        if "battery" in s.failures:  # the monitor is off: nothing measured
            return {"timestamp": us(s.t), "connected": False, "voltage_v": 0.0, "current_a": -1.0,
                    "remaining": -1.0, "cell_count": 0, "warning": BATTERY_WARNING_NONE}
        warning = (BATTERY_WARNING_CRITICAL if s.battery <= self.critical else
                   BATTERY_WARNING_LOW if s.battery <= self.low else BATTERY_WARNING_NONE)
        return {"timestamp": us(s.t), "connected": True, "voltage_v": s.voltage, "current_a": 10.0 if s.armed else 0.5,
                "remaining": s.battery, "cell_count": self.cells, "warning": warning}
