"""Follow-me as PX4's AUTO_FOLLOW_TARGET flies it (FlightTaskAutoFollowTarget), from FOLLOW_TARGET messages.

The target's reported position (lat/lon, AMSL altitude) is low-pass filtered (time constant FLW_TGT_RS s: lower
is more responsive); its course (direction of motion, from the reported velocity or, when that is zero or
unknown, from its displacement between reports) is tracked only while it moves faster than 1 m/s, as PX4 freezes
it below that speed. The vehicle keeps FLW_TGT_DST m from the target at FLW_TGT_FA degrees from the target's
course (0 in front, 90 right, 180 behind, clockwise), moving around the target at most at FLW_TGT_MAX_VEL m/s
tangentially; height FLW_TGT_HT m above home (FLW_TGT_ALT_M 0; 1, terrain, is the same on flat ground) or above
the target (2, 3D tracking), never below PX4's 1 m minimum safety altitude. It climbs or descends first when
more than 3 m off the height (ALT_ACCEPTANCE_THRESHOLD), faces the target when more than 1 m away, and holds
where it is when the target has not been heard for 1.5 s (TARGET_ESTIMATOR_TIMEOUT, on the link's wall clock:
MAVSDK sends the target at 1 Hz of wall time whatever the simulation's speed-up). A setpoint outside the
geofence is not taken (the vehicle waits at the last valid one)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from radseek.coordinates import Home, geodetic_to_enu, wrap_pi

MIN_SAFETY_ALT_M = 1.0
ALT_ACCEPTANCE_M = 3.0
TIMEOUT_S = 1.5
COURSE_MIN_SPEED = 1.0  # m/s
YAW_MIN_DISTANCE = 1.0  # m


@dataclass
class FollowParams:
    """PX4's FLW_TGT_* parameters (defaults as PX4's)."""

    height: float = 8.0  # m [FLW_TGT_HT]
    distance: float = 8.0  # m [FLW_TGT_DST]
    angle_deg: float = 180.0  # deg from the target's course, clockwise [FLW_TGT_FA]
    responsiveness: float = 0.1  # s, filter time constant [FLW_TGT_RS]
    alt_mode: int = 0  # 0 constant above home, 1 terrain (flat: as 0), 2 track the target [FLW_TGT_ALT_M]
    max_vel: float = 5.0  # m/s tangential [FLW_TGT_MAX_VEL]


class FollowTarget:
    """The target as last reported, filtered, and the setpoint that follows it (ENU, m)."""

    def __init__(self, home: Home, allowed: Callable[[np.ndarray], bool] = lambda p: True):
        self.home = home
        self.p = FollowParams()
        self.allowed = allowed  # the geofence
        self.raw: np.ndarray | None = None  # ENU m, z above home
        self.raw_vel: np.ndarray | None = None
        self.raw_t: float | None = None  # sim s of the last report
        self.last_rx: float | None = None  # wall s of the last report
        self.filtered: np.ndarray | None = None
        self.course = math.pi / 2  # ENU rad; PX4 starts facing north
        self.orbit_angle: float | None = None  # ENU rad of the vehicle about the target
        self.setpoint: np.ndarray | None = None
        self.count = 0

    def receive(self, msg, t: float, now_wall: float) -> None:
        """A FOLLOW_TARGET message; raises ValueError when its position is unusable."""
        lat, lon, alt = msg.lat / 1e7, msg.lon / 1e7, float(msg.alt)
        if not (-90 <= lat <= 90 and -180 <= lon <= 180 and math.isfinite(alt)) or (msg.lat == 0 and msg.lon == 0):
            raise ValueError(f"target position {lat}, {lon}, {alt} unusable")
        pos = geodetic_to_enu(self.home, lat, lon, alt)
        vel = None
        v_ned = [float(c) for c in msg.vel]
        if msg.est_capabilities & 0b10 and all(math.isfinite(c) for c in v_ned) and any(v_ned):
            vel = np.array([v_ned[1], v_ned[0], -v_ned[2]])
        elif self.raw is not None and self.raw_t is not None and t > self.raw_t:
            vel = (pos - self.raw) / (t - self.raw_t)  # from its displacement
        if vel is not None and math.hypot(vel[0], vel[1]) > COURSE_MIN_SPEED:
            self.course = math.atan2(vel[1], vel[0])
        self.raw, self.raw_vel, self.raw_t, self.last_rx = pos, vel, t, now_wall
        self.count += 1

    def expire(self, now_wall: float) -> bool:
        """Forget a target not heard for TIMEOUT_S; True if it was just lost."""
        if self.raw is not None and self.last_rx is not None and now_wall - self.last_rx > TIMEOUT_S:
            self.raw = self.filtered = None
            return True
        return False

    def reset(self) -> None:
        """Entering the mode: the orbit angle starts where the vehicle is."""
        self.orbit_angle, self.setpoint = None, None

    def step(self, pos: np.ndarray, dt: float) -> tuple[np.ndarray, float | None]:
        """The position setpoint and yaw (ENU) for this step; the vehicle's own position when no target."""
        if self.raw is None:
            self.filtered = None
            hold = self.setpoint if self.setpoint is not None else pos.copy()
            self.setpoint = hold
            return hold, None
        if self.filtered is None:
            self.filtered = self.raw.copy()
        else:
            tau = max(self.p.responsiveness, 0.0)
            self.filtered = self.filtered + (self.raw - self.filtered) * (dt / (tau + dt))
        tgt = self.filtered
        rel = pos[:2] - tgt[:2]
        if self.orbit_angle is None:
            self.orbit_angle = math.atan2(rel[1], rel[0]) if np.hypot(*rel) > 1e-6 else self.course + math.pi
        want = wrap_pi(self.course - math.radians(self.p.angle_deg))  # clockwise from the course
        step_max = self.p.max_vel / max(self.p.distance, 1e-3) * dt
        self.orbit_angle = wrap_pi(self.orbit_angle + max(-step_max, min(step_max, wrap_pi(want - self.orbit_angle))))
        a = self.orbit_angle
        z = self.p.height + (tgt[2] if self.p.alt_mode == 2 else 0.0)
        desired = np.array([tgt[0] + self.p.distance * math.cos(a), tgt[1] + self.p.distance * math.sin(a),
                            max(z, MIN_SAFETY_ALT_M)])
        if abs(pos[2] - desired[2]) > ALT_ACCEPTANCE_M:
            desired[:2] = pos[:2]  # height first
        if self.allowed(desired):
            self.setpoint = desired
        elif self.setpoint is None:
            self.setpoint = pos.copy()
        yaw = math.atan2(-rel[1], -rel[0]) if np.hypot(*rel) > YAW_MIN_DISTANCE else None
        return self.setpoint, yaw
