"""MANUAL_CONTROL (virtual sticks, MAVSDK's manual_control plugin) as PX4 reads it in POSCTL and ALTCTL.

PX4's scaling: x pitch stick (+forward), y roll stick (+right), r yaw stick (+clockwise), each -1000..1000; z
throttle 0..1000 with 500 centred (PX4 maps z to -1..1 as z/500 - 1: in POSCTL/ALTCTL 500 is "hold altitude").
Sticks inside MAN_DEADZONE (0.1) count as centred. In POSCTL the sticks command velocities in the body frame:
forward/right up to MPC_VEL_MANUAL (10 m/s), up to MPC_Z_VEL_MAX_UP / down to MPC_Z_VEL_MAX_DN, yaw rate up to
MPC_MAN_Y_MAX (150 deg/s); centred sticks brake and hold the position. ALTCTL is the same vertically and in yaw;
horizontally the sticks tilt the vehicle, approximated here as the same velocity command but with centred sticks
letting the vehicle drift (its horizontal speed decays with a 2 s time constant) instead of holding position.
Throttle above centre lifts a landed, armed vehicle off the ground.

The stream counts as alive while the last MANUAL_CONTROL is younger than COM_RC_LOSS_T (0.5 s) on the link's wall
clock (MAVSDK sends at the caller's pace in wall time); once lost, the sticks read as centred (hold) and the loss
is announced."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DEADZONE = 0.1  # MAN_DEADZONE
VEL_MANUAL = 10.0  # m/s, MPC_VEL_MANUAL
YAW_RATE_MAX = math.radians(150.0)  # rad/s, MPC_MAN_Y_MAX
LOSS_S = 0.5  # s, COM_RC_LOSS_T
ALTCTL_DRIFT_TAU_S = 2.0


@dataclass(frozen=True)
class Sticks:
    """Normalised sticks: forward, right, yaw (clockwise) in -1..1, throttle -1..1 (0 centred)."""

    forward: float
    right: float
    throttle: float
    yaw: float


def _dz(v: float) -> float:
    """Deadzone, rescaled so that full deflection stays 1."""
    if abs(v) <= DEADZONE:
        return 0.0
    return math.copysign((abs(v) - DEADZONE) / (1 - DEADZONE), v)


def sticks_from_msg(msg) -> Sticks:
    """Decode MANUAL_CONTROL; raises ValueError for a value outside PX4's ranges."""
    x, y, z, r = (int(msg.x), int(msg.y), int(msg.z), int(msg.r))
    if not (-1000 <= x <= 1000 and -1000 <= y <= 1000 and -1000 <= r <= 1000 and -1000 <= z <= 1000):
        raise ValueError(f"stick values x={x} y={y} z={z} r={r} outside -1000..1000")
    throttle = min(max(z / 500.0 - 1.0, -1.0), 1.0)
    return Sticks(_dz(x / 1000), _dz(y / 1000), _dz(throttle), _dz(r / 1000))


class ManualControl:
    """The last sticks and when they came (link clock)."""

    def __init__(self):
        self.sticks: Sticks | None = None
        self.last_rx: float | None = None
        self.count = 0

    def receive(self, sticks: Sticks, now_wall: float) -> None:
        self.sticks, self.last_rx = sticks, now_wall
        self.count += 1

    def expire(self, now_wall: float) -> bool:
        """Centre the sticks once the stream is lost; True when it was just lost."""
        if self.sticks is not None and self.last_rx is not None and now_wall - self.last_rx > LOSS_S:
            self.sticks = None
            return True
        return False


def command(sticks: Sticks | None, yaw: float, vel: np.ndarray, up_max: float, down_max: float, hold_xy: bool,
            dt: float) -> tuple[np.ndarray, float]:
    """The ENU velocity and ENU yaw rate the sticks ask for. ``hold_xy`` (POSCTL): centred sticks stop the
    vehicle; otherwise (ALTCTL) its horizontal velocity decays."""
    s = sticks or Sticks(0.0, 0.0, 0.0, 0.0)
    fwd = np.array([math.cos(yaw), math.sin(yaw)])
    right = np.array([math.sin(yaw), -math.cos(yaw)])
    v = np.zeros(3)
    if s.forward or s.right or hold_xy:
        v[:2] = (s.forward * fwd + s.right * right) * VEL_MANUAL
    else:
        v[:2] = vel[:2] * math.exp(-dt / ALTCTL_DRIFT_TAU_S)
    v[2] = s.throttle * (up_max if s.throttle > 0 else down_max)
    return v, -s.yaw * YAW_RATE_MAX
