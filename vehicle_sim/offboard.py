"""Offboard control as PX4 has it: SET_POSITION_TARGET_LOCAL_NED / SET_POSITION_TARGET_GLOBAL_INT
setpoints (position, velocity, or both; yaw or yaw rate) and SET_ATTITUDE_TARGET (attitude quaternion or body
rates, with a collective thrust), a setpoint stream required before the switch to OFFBOARD and all along it,
and a failsafe when the stream stops.

Attitude and rate setpoints fly a point-mass multicopter (``attitude_step``): the attitude is reached at once
(the attitude loop is fast next to the motion; a rate setpoint integrates the body rates into it), the thrust
accelerates along the body's -z axis by g * thrust / MPC_THR_HOVER, gravity pulls down, and a linear drag
(``DRAG_PER_S``) bounds the speed: a tilt becomes a horizontal acceleration, a thrust above the hover thrust a
climb. The ground stops a descent and holds the vehicle (landed) while the thrust cannot lift it. The hover
thrust is PX4's MPC_THR_HOVER (0.5 by default, as PX4's).

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


GRAVITY = 9.80665
DRAG_PER_S = 0.5  # linear drag, 1/s: terminal speed g tan(tilt) / DRAG_PER_S (10 m/s at 30 deg)
MAX_SPEED = 20.0  # m/s, any axis, in attitude control
ATT_TYPEMASK_RATES = 0b111  # body roll / pitch / yaw rate ignored
ATT_TYPEMASK_THRUST = 1 << 6  # THROTTLE_IGNORE
ATT_TYPEMASK_ATTITUDE = 1 << 7  # ATTITUDE_IGNORE


@dataclass(frozen=True)
class AttitudeTarget:
    """SET_ATTITUDE_TARGET: attitude (roll, pitch, yaw NED rad) or body rates (FRD rad/s), and thrust (0..1)."""

    attitude: tuple[float, float, float] | None
    rates: tuple[float, float, float] | None
    thrust: float | None


@dataclass(frozen=True)
class Setpoint:
    """One offboard setpoint in local ENU: position and/or velocity; yaw (ENU rad) or yaw rate (rad/s); or an
    attitude target (the rest None)."""

    pos: np.ndarray | None
    vel: np.ndarray | None
    yaw: float | None
    yaw_rate: float | None
    attitude: AttitudeTarget | None = None


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


def euler_from_quaternion(q) -> tuple[float, float, float]:
    """Roll, pitch, yaw (ZYX, rad) of the rotation body -> NED given as w, x, y, z."""
    w, x, y, z = (float(c) for c in q)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not math.isfinite(n) or n < 1e-6:
        raise SetpointError(f"quaternion {list(q)} is not a rotation")
    w, x, y, z = w / n, x / n, y / n, z / n
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def attitude_setpoint_from_msg(msg) -> Setpoint:
    """Decode SET_ATTITUDE_TARGET; raises SetpointError if unusable."""
    mask = int(msg.type_mask)
    att = None if mask & ATT_TYPEMASK_ATTITUDE else euler_from_quaternion(msg.q)
    rates = None
    if mask & ATT_TYPEMASK_RATES != ATT_TYPEMASK_RATES:
        rates = tuple(0.0 if mask & (1 << k) else float(v)
                      for k, v in enumerate((msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate)))
        if not all(math.isfinite(r) for r in rates):
            raise SetpointError(f"non-finite body rates {rates}")
    if att is None and rates is None:
        raise SetpointError("neither attitude nor body rates")
    thrust = None if mask & ATT_TYPEMASK_THRUST else float(msg.thrust)
    if thrust is not None and not (math.isfinite(thrust) and 0.0 <= thrust <= 1.0):
        raise SetpointError(f"thrust {thrust} not in [0, 1]")
    return Setpoint(None, None, None, None, AttitudeTarget(att, None if att is not None else rates, thrust))


def attitude_step(pos: np.ndarray, vel: np.ndarray, att: tuple[float, float, float], target: AttitudeTarget,
                  hover_thrust: float, dt: float) -> tuple[np.ndarray, np.ndarray, tuple[float, float, float]]:
    """One fixed step of the point-mass multicopter under an attitude target; returns position, velocity (ENU)
    and the attitude flown (roll, pitch, yaw NED)."""
    if target.attitude is not None:
        roll, pitch, yaw = target.attitude
    else:  # body rates, small angles: Euler rates ~ body rates
        p, q, r = target.rates
        roll, pitch, yaw = att[0] + p * dt, att[1] + q * dt, wrap_pi(att[2] + r * dt)
    thrust = hover_thrust if target.thrust is None else target.thrust
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw),
                              math.sin(yaw))
    body_z_ned = np.array([cr * sp * cy + sr * sy, cr * sp * sy - sr * cy, cr * cp])  # body +z (down) in NED
    a_ned = -GRAVITY * thrust / hover_thrust * body_z_ned + np.array([0.0, 0.0, GRAVITY])
    a = enu_to_ned(a_ned) - DRAG_PER_S * vel
    new_vel = np.clip(vel + a * dt, -MAX_SPEED, MAX_SPEED)
    new_pos = pos + (vel + new_vel) / 2 * dt
    if new_pos[2] <= 0.0:  # on the ground: it stops there
        new_pos[2] = 0.0
        new_vel = np.zeros(3) if new_vel[2] <= 0 else np.array([0.0, 0.0, new_vel[2]])
    return new_pos, new_vel, (roll, pitch, yaw)


def lifts_off(target: AttitudeTarget, hover_thrust: float) -> bool:
    """Whether the target's thrust, at its tilt, overcomes gravity."""
    thrust = hover_thrust if target.thrust is None else target.thrust
    roll, pitch = target.attitude[:2] if target.attitude is not None else (0.0, 0.0)
    return thrust / hover_thrust * math.cos(roll) * math.cos(pitch) > 1.0 + 1e-6


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
