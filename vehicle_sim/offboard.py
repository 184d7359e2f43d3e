"""Offboard control as PX4 has it: SET_POSITION_TARGET_LOCAL_NED / SET_POSITION_TARGET_GLOBAL_INT
setpoints (position, velocity, or both; yaw or yaw rate), a setpoint stream required before the switch
to OFFBOARD and all along it, and a failsafe when the stream stops.

- The stream counts as alive while the last setpoint is younger than COM_OF_LOSS_T (1 s, PX4's default),
  measured on the link clock like the GCS link loss: the companion computer streams in wall time
  (MAVSDK every 50 ms), so a sim-time timeout would fire N times early at speed-up N.
- DO_SET_MODE OFFBOARD without a live stream is DENIED (PX4: "Offboard not available").
- Stream lost while in OFFBOARD: HOLD (PX4's COM_OBL_RC_ACT falls back to Hold without an RC), announced.
- A position setpoint outside the geofence is ignored (the vehicle keeps the last valid one) and
  announced once; a velocity setpoint is stopped at the fence by the vehicle's breach check.

Frames: LOCAL_NED (and LOCAL_OFFSET_NED / BODY_NED / BODY_OFFSET_NED for velocities) about home; global
setpoints in GLOBAL_INT (AMSL), GLOBAL_RELATIVE_ALT_INT or GLOBAL_TERRAIN_ALT_INT (flat ground: as
relative). ``Setpoint`` holds the target in the navigator's ENU frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as M

from radseek.coordinates import Home, enu_to_ned, geodetic_to_enu, wrap_pi, yaw_ned_to_enu
from vehicle_sim.motion import MotionLimits, accelerate, turn

IGNORE_POS = 0b111
IGNORE_VEL = 0b111 << 3
IGNORE_ACC = 0b111 << 6
IGNORE_YAW = 1 << 10
IGNORE_YAW_RATE = 1 << 11
LOCAL_FRAMES = {M.MAV_FRAME_LOCAL_NED, M.MAV_FRAME_LOCAL_OFFSET_NED, M.MAV_FRAME_BODY_NED,
                M.MAV_FRAME_BODY_OFFSET_NED, M.MAV_FRAME_BODY_FRD, M.MAV_FRAME_LOCAL_FRD}
GLOBAL_FRAMES = {M.MAV_FRAME_GLOBAL_INT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
                 M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_TERRAIN_ALT}


@dataclass(frozen=True)
class Setpoint:
    """One offboard setpoint in local ENU: position and/or velocity; yaw (ENU rad) or yaw rate (rad/s)."""

    pos: np.ndarray | None
    vel: np.ndarray | None
    yaw: float | None
    yaw_rate: float | None


class SetpointError(ValueError):
    pass


def _finite_or_none(values, ignore: bool) -> np.ndarray | None:
    if ignore:
        return None
    v = np.array([float(c) for c in values])
    if not np.all(np.isfinite(v)):
        raise SetpointError(f"non-finite components {v}")
    return v


def setpoint_from_msg(msg, home: Home, yaw_enu_now: float) -> Setpoint:
    """Decode SET_POSITION_TARGET_LOCAL_NED / _GLOBAL_INT; raises SetpointError if unusable."""
    mask = int(msg.type_mask)
    frame = int(msg.coordinate_frame)
    if msg.get_type() == "SET_POSITION_TARGET_GLOBAL_INT":
        if frame not in GLOBAL_FRAMES:
            raise SetpointError(f"frame {frame} is not a global frame")
        pos = None
        if not mask & IGNORE_POS:
            lat, lon, alt = msg.lat_int / 1e7, msg.lon_int / 1e7, float(msg.alt)
            if not (-90 <= lat <= 90 and -180 <= lon <= 180 and math.isfinite(alt)):
                raise SetpointError(f"invalid position {lat}, {lon}, {alt}")
            amsl = frame in (M.MAV_FRAME_GLOBAL_INT, M.MAV_FRAME_GLOBAL)
            pos = geodetic_to_enu(home, lat, lon, alt if amsl else alt + home.alt_m)
        vel_ned = _finite_or_none((msg.vx, msg.vy, msg.vz), bool(mask & IGNORE_VEL))
    else:
        if frame not in LOCAL_FRAMES:
            raise SetpointError(f"frame {frame} is not a local frame")
        p_ned = _finite_or_none((msg.x, msg.y, msg.z), bool(mask & IGNORE_POS))
        pos = None if p_ned is None else enu_to_ned(p_ned)  # the swap is its own inverse, up to z's sign
        vel_ned = _finite_or_none((msg.vx, msg.vy, msg.vz), bool(mask & IGNORE_VEL))
        if vel_ned is not None and frame in (M.MAV_FRAME_BODY_NED, M.MAV_FRAME_BODY_OFFSET_NED, M.MAV_FRAME_BODY_FRD):
            yaw_ned = math.pi / 2 - yaw_enu_now  # body forward/right -> north/east
            c, s = math.cos(yaw_ned), math.sin(yaw_ned)
            vel_ned = np.array([c * vel_ned[0] - s * vel_ned[1], s * vel_ned[0] + c * vel_ned[1], vel_ned[2]])
    vel = None if vel_ned is None else enu_to_ned(vel_ned)
    if pos is None and vel is None:
        raise SetpointError("neither position nor velocity (acceleration/thrust setpoints are not supported)")
    yaw = None
    if not mask & IGNORE_YAW and math.isfinite(float(msg.yaw)):
        yaw = yaw_ned_to_enu(float(msg.yaw))
    yaw_rate = None
    if not mask & IGNORE_YAW_RATE and math.isfinite(float(msg.yaw_rate)):
        yaw_rate = -float(msg.yaw_rate)  # NED rate (clockwise) -> ENU (counter-clockwise)
    return Setpoint(pos, vel, yaw, yaw_rate)


class OffboardStream:
    """The last setpoint and when it came (link clock); ``alive`` says whether the stream is on."""

    def __init__(self, loss_timeout_s: float = 1.0):
        self.loss_timeout_s = loss_timeout_s  # COM_OF_LOSS_T
        self.setpoint: Setpoint | None = None
        self.last_rx: float | None = None
        self.count = 0

    def receive(self, sp: Setpoint, now_wall: float) -> None:
        self.setpoint, self.last_rx = sp, now_wall
        self.count += 1

    def alive(self, now_wall: float) -> bool:
        return self.last_rx is not None and now_wall - self.last_rx <= self.loss_timeout_s


def velocity_step(pos: np.ndarray, vel: np.ndarray, yaw: float, v_des: np.ndarray, yaw_des: float | None,
                  yaw_rate: float | None, limits: MotionLimits, dt: float) -> tuple[np.ndarray, np.ndarray, float]:
    """One fixed step tracking velocity ``v_des`` (ENU m/s) within the speed and acceleration limits;
    the ground (z = 0) stops a descent."""
    v = np.array(v_des, dtype=float)
    h = math.hypot(v[0], v[1])
    if h > limits.max_speed_xy:
        v[:2] *= limits.max_speed_xy / h
    v[2] = min(max(v[2], -limits.max_speed_down), limits.max_speed_up)
    new_pos, new_vel = accelerate(pos, vel, v, limits, dt)
    if new_pos[2] < 0:
        new_pos[2], new_vel[2] = 0.0, 0.0
    new_yaw = yaw
    if yaw_des is not None:
        new_yaw = turn(yaw, wrap_pi(yaw_des - yaw), limits, dt)
    elif yaw_rate is not None:
        new_yaw = turn(yaw, yaw_rate * dt, limits, dt)
    return new_pos, new_vel, new_yaw
