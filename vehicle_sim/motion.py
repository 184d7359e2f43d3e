"""Pure multicopter kinematics: a point mass that flies straight at a target with speed,
acceleration and yaw-rate limits, stepped in fixed sim steps (ArduPilot SITL style).

The speed profile is trapezoidal: accelerate at ``max_accel``, cruise at the speed limit of the
flight direction, and brake at ``BRAKE_FRACTION * max_accel`` so as to stop exactly on the target
(``v <= sqrt(2 a_b d)``; braking a little below the limit lets the accel-limited velocity track the
profile in discrete steps without overshoot). For a rest-to-rest straight leg long enough to reach
cruise speed v, the arrival time is ``d / v + v / (2 a) + v / (2 a_b)`` (``straight_leg_time``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from radseek.coordinates import wrap_pi

BRAKE_FRACTION = 0.8


@dataclass(frozen=True)
class MotionLimits:
    """Multicopter limits (PX4 MPC_* names in brackets). Units: m, s, rad."""

    max_speed_xy: float = 3.0  # m/s, (0, 20] horizontal cruise speed [MPC_XY_CRUISE]
    max_speed_up: float = 2.0  # m/s, (0, 10] [MPC_Z_VEL_MAX_UP]
    max_speed_down: float = 1.0  # m/s, (0, 10] [MPC_Z_VEL_MAX_DN]
    max_accel: float = 2.0  # m/s^2, (0, 10] [MPC_ACC_HOR]
    max_yaw_rate: float = math.radians(60.0)  # rad/s, (0, 2 pi] [MPC_YAWRAUTO_MAX]

    def __post_init__(self) -> None:
        for name, hi in (("max_speed_xy", 20), ("max_speed_up", 10), ("max_speed_down", 10), ("max_accel", 10),
                         ("max_yaw_rate", 2 * math.pi)):
            v = getattr(self, name)
            if not (0 < v <= hi):
                raise ValueError(f"{name}={v} must be in (0, {hi}]")

    def with_speed_xy(self, speed: float) -> MotionLimits:
        return MotionLimits(min(max(speed, 0.1), 20.0), self.max_speed_up, self.max_speed_down,
                            self.max_accel, self.max_yaw_rate)


def direction_speed_limit(direction: np.ndarray, limits: MotionLimits) -> float:
    """Largest speed along unit vector ``direction`` that respects the horizontal and vertical limits."""
    h = math.hypot(direction[0], direction[1])
    v = math.inf
    if h > 1e-9:
        v = limits.max_speed_xy / h
    if direction[2] > 1e-9:
        v = min(v, limits.max_speed_up / direction[2])
    elif direction[2] < -1e-9:
        v = min(v, limits.max_speed_down / -direction[2])
    return v


def step(
    pos: np.ndarray, vel: np.ndarray, yaw: float, target: np.ndarray, target_yaw: float | None,
    limits: MotionLimits, dt: float,
) -> tuple[np.ndarray, np.ndarray, float]:
    """One fixed step towards ``target`` (ENU m) and ``target_yaw`` (rad, None = keep). Returns new state."""
    d = np.asarray(target, dtype=float) - pos
    dist = float(np.linalg.norm(d))
    if dist < 1e-9:
        v_des = np.zeros(3)
    else:
        direction = d / dist
        brake = BRAKE_FRACTION * limits.max_accel
        speed = min(direction_speed_limit(direction, limits), math.sqrt(2.0 * brake * dist), dist / dt)
        v_des = direction * speed
    new_pos, new_vel = accelerate(pos, vel, v_des, limits, dt)
    if dist > 1e-9 and float(np.dot(target - new_pos, d)) < 0:  # never step past the target
        new_pos = np.array(target, dtype=float)
    new_yaw = yaw
    if target_yaw is not None and math.isfinite(target_yaw):
        new_yaw = turn(yaw, wrap_pi(target_yaw - yaw), limits, dt)
    return new_pos, new_vel, new_yaw


def accelerate(pos: np.ndarray, vel: np.ndarray, v_des: np.ndarray, limits: MotionLimits,
               dt: float) -> tuple[np.ndarray, np.ndarray]:
    """One step of the velocity towards ``v_des`` changing by at most ``max_accel * dt``, and the position moved
    by the step's mean velocity (trapezoid rule). Returns (new position, new velocity)."""
    dv = v_des - vel
    n = float(np.linalg.norm(dv))
    if n > limits.max_accel * dt:
        dv *= limits.max_accel * dt / n
    new_vel = vel + dv
    return pos + 0.5 * (vel + new_vel) * dt, new_vel


def turn(yaw: float, delta: float, limits: MotionLimits, dt: float) -> float:
    """``yaw`` turned by ``delta`` rad, at most ``max_yaw_rate * dt`` either way, wrapped to (-pi, pi]."""
    lim = limits.max_yaw_rate * dt
    return wrap_pi(yaw + max(-lim, min(lim, delta)))


def arrived(pos: np.ndarray, vel: np.ndarray, target: np.ndarray, radius: float = 0.1, speed: float = 0.2) -> bool:
    """Within ``radius`` m of the target and nearly stopped."""
    return float(np.linalg.norm(np.asarray(target) - pos)) <= radius and float(np.linalg.norm(vel)) <= speed


def straight_leg_time(distance: float, speed: float, accel: float, brake_fraction: float = BRAKE_FRACTION) -> float:
    """Analytic rest-to-rest time of the profile: accelerate at ``accel``, cruise at ``speed``, brake at
    ``brake_fraction * accel`` (triangular when the leg is too short to reach ``speed``)."""
    brake = brake_fraction * accel
    d_ramps = speed * speed / (2 * accel) + speed * speed / (2 * brake)
    if distance <= d_ramps:
        v = math.sqrt(2 * distance * accel * brake / (accel + brake))
        return v / accel + v / brake
    return distance / speed + speed / (2 * accel) + speed / (2 * brake)
