"""Flight modes and mission execution: turns the current mode and mission item into a motion target
and steps the kinematics (``motion.step``) in fixed sim steps.

Modes are PX4's (the autopilot type we announce), so MAVSDK and QGroundControl name them right:
HOLD (AUTO.LOITER), TAKEOFF, MISSION, RTL, LAND, POSCTL and ALTCTL (virtual sticks from ``manual_control``;
without sticks ever received POSCTL holds), OFFBOARD (setpoints from ``offboard``), ORBIT (MAV_CMD_DO_ORBIT; PX4
reports it as POSCTL sub-mode ORBIT) and FOLLOW (AUTO.FOLLOW_TARGET, from ``follow_target``). The navigator works in
the vehicle's *estimated* local ENU frame: it flies on its own (drifting) estimate, like a real
GPS-denied vehicle. Mission items are converted from lat/lon here with ``frames``.

Dwell points are NAV_WAYPOINT items whose hold time (param1) is the longest dwell allowed; a client
that has decided the dwell is long enough ends it early with DO_SET_MISSION_CURRENT / MISSION_SET_CURRENT
to the next item (see docs/vehicle.md).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from enum import Enum

import numpy as np
from pymavlink.dialects.v20 import common as M

from radseek.coordinates import Home, geodetic_to_enu, yaw_ned_to_enu
from vehicle_sim import motion
from vehicle_sim.mission_protocol import GLOBAL_FRAMES, MissionItem


class Mode(Enum):
    HOLD = "HOLD"
    POSCTL = "POSCTL"
    TAKEOFF = "TAKEOFF"
    MISSION = "MISSION"
    RTL = "RTL"
    LAND = "LAND"
    OFFBOARD = "OFFBOARD"
    ORBIT = "ORBIT"
    ALTCTL = "ALTCTL"
    FOLLOW = "FOLLOW"


# PX4 custom_mode = main_mode << 16 | sub_mode << 24
PX4_MAIN_ALTCTL, PX4_MAIN_POSCTL, PX4_MAIN_AUTO, PX4_MAIN_OFFBOARD = 2, 3, 4, 6
PX4_SUB_POSCTL_ORBIT = 1
PX4_SUB = {Mode.TAKEOFF: 2, Mode.HOLD: 3, Mode.MISSION: 4, Mode.RTL: 5, Mode.LAND: 6, Mode.FOLLOW: 8}
MANUAL_MODES = (Mode.POSCTL, Mode.ALTCTL)


def px4_custom_mode(mode: Mode) -> int:
    if mode is Mode.POSCTL:
        return PX4_MAIN_POSCTL << 16
    if mode is Mode.ALTCTL:
        return PX4_MAIN_ALTCTL << 16
    if mode is Mode.ORBIT:
        return (PX4_MAIN_POSCTL << 16) | (PX4_SUB_POSCTL_ORBIT << 24)
    if mode is Mode.OFFBOARD:
        return PX4_MAIN_OFFBOARD << 16
    return (PX4_MAIN_AUTO << 16) | (PX4_SUB[mode] << 24)


def mode_from_px4(main_mode: int, sub_mode: int) -> Mode | None:
    """The mode a DO_SET_MODE / SET_MODE asks for (ORBIT is entered by DO_ORBIT only)."""
    if main_mode == PX4_MAIN_OFFBOARD:
        return Mode.OFFBOARD
    if main_mode == PX4_MAIN_POSCTL:
        return Mode.POSCTL
    if main_mode == PX4_MAIN_ALTCTL:
        return Mode.ALTCTL
    if main_mode == PX4_MAIN_AUTO:
        for mode, sub in PX4_SUB.items():
            if sub == sub_mode:
                return mode
    return None


@dataclass(frozen=True)
class NavParams:
    takeoff_alt: float = 2.5  # m above home, (0.5, 100] [MIS_TAKEOFF_ALT]
    rtl_alt: float = 5.0  # m above home, (1, 120] [RTL_RETURN_ALT]
    land_speed: float = 0.7  # m/s, (0.1, 3] [MPC_LAND_SPEED]
    acceptance_radius: float = 0.2  # m, (0.01, 10] [NAV_ACC_RAD]
    disarm_after_land_s: float = 2.0  # s, [0, 60] [COM_DISARM_LAND]
    pass_radius: float = 0.5  # m, [0, 5]: a waypoint without hold followed by another is passed within this
    hover_thrust: float = 0.5  # [0.1, 0.9], the thrust that holds altitude in attitude offboard [MPC_THR_HOVER]


class MissionState:  # MAV_MISSION_STATE
    UNKNOWN, NO_MISSION, NOT_STARTED, ACTIVE, PAUSED, COMPLETE = range(6)


@dataclass
class Orbit:
    """MAV_CMD_DO_ORBIT in ENU: centre (m), radius (m, > 0), signed angular direction (+1 counter-
    clockwise seen from above, as ENU angles grow; MAVLink's positive radius = clockwise = -1), speed
    (m/s), yaw behaviour (ORBIT_YAW_BEHAVIOUR), orbits to fly (inf = until another command)."""

    center: np.ndarray
    radius: float
    direction: float
    speed: float
    yaw_behaviour: int
    orbits: float = math.inf
    circling: bool = False
    angle: float = 0.0  # current angle about the centre (ENU rad)
    swept: float = 0.0  # rad flown on the circle
    tangential: float = 0.0  # current speed along the circle, m/s
    initial_yaw: float = 0.0


class Navigator:
    def __init__(self, home: Home, limits: motion.MotionLimits | None = None, params: NavParams | None = None):
        self.home = home
        self.base_limits = limits or motion.MotionLimits()
        self.limits = self.base_limits
        self.p = params or NavParams()
        self.pos = np.zeros(3)  # estimated ENU m
        self.vel = np.zeros(3)
        self.accel = np.zeros(3)
        self.yaw = math.pi / 2  # ENU: facing north
        self.armed = False
        self.landed = True
        self.mode = Mode.HOLD
        self.target = self.pos.copy()
        self.target_yaw: float | None = None
        self.items: list[MissionItem] = []
        self.seq = 0
        self.started = False  # the mission has been started since it was uploaded
        self.complete = False
        self._phase = "go"
        self._hold_until = 0.0
        self._landed_at: float | None = None
        self._t = 0.0
        self.events: list[tuple[str, object]] = []  # ("reached", seq) | ("text", str) | ("mode", Mode)
        self.offboard_setpoint = None  # offboard.Setpoint, set by the vehicle from the stream
        self.attitude: tuple[float, float, float] | None = None  # roll, pitch, yaw NED flown in attitude offboard
        self.orbit: Orbit | None = None
        self.follow = None  # follow_target.FollowTarget, set by the vehicle (FOLLOW holds without one)
        self.manual = None  # manual_control.ManualControl, set by the vehicle
        self.rally_points: list[np.ndarray] = []  # ENU; RTL goes to the nearest of home and these
        self._rtl_home = np.zeros(2)
        self.launch_xy = np.zeros(2)  # ENU x-y where the vehicle started: RTL's home (the frame origin by default)

    # -- state queries -------------------------------------------------------------------------
    @property
    def in_air(self) -> bool:
        return not self.landed

    @property
    def landing(self) -> bool:
        return self.in_air and (self.mode is Mode.LAND or (self._phase == "descend"))

    @property
    def mission_state(self) -> int:
        if not self.items:
            return MissionState.NO_MISSION
        if self.complete:
            return MissionState.COMPLETE
        if not self.started:
            return MissionState.NOT_STARTED
        return MissionState.ACTIVE if self.mode is Mode.MISSION else MissionState.PAUSED

    def item_target(self, item: MissionItem) -> np.ndarray:
        """ENU position of a positional item (lat = lon = 0 means 'here')."""
        if item.frame not in GLOBAL_FRAMES:
            return self.pos.copy()
        rel = item.frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
        alt = item.z + self.home.alt_m if rel else item.z
        if item.x == 0 and item.y == 0:
            p = self.pos.copy()
            p[2] = alt - self.home.alt_m
            return p
        return geodetic_to_enu(self.home, item.x / 1e7, item.y / 1e7, alt)

    # -- commands (return True if accepted) ----------------------------------------------------
    def _set_mode(self, mode: Mode) -> None:
        if mode is not self.mode:
            self.mode = mode
            self.events.append(("mode", mode))
        self._phase = "go"

    def arm(self) -> bool:
        if not self.armed:
            self.armed = True
            self._landed_at = None
            self.events.append(("text", "Armed"))
        return True

    def disarm(self, force: bool = False) -> bool:
        if self.in_air and not force:
            return False
        self.armed = False
        self.vel[:] = 0
        self.events.append(("text", "Disarmed"))
        return True

    def hold(self) -> bool:
        self._set_mode(Mode.HOLD)
        self.target, self.target_yaw = self._stop_point(), None
        return True

    def _stop_point(self) -> np.ndarray:
        """Where the vehicle can stop: position plus the braking distance along the velocity."""
        v = float(np.linalg.norm(self.vel))
        if self.landed or v < 1e-6:
            return self.pos.copy()
        return self.pos + self.vel / v * (v * v / (2 * self.limits.max_accel))

    def takeoff(self, alt: float | None = None) -> bool:
        if not self.armed:
            return False
        alt = self.p.takeoff_alt if alt is None or not math.isfinite(alt) else alt
        self._set_mode(Mode.TAKEOFF)
        self.target = np.array([self.pos[0], self.pos[1], max(alt, 0.5)])
        self.target_yaw = None
        self.landed = False
        return True

    def land(self) -> bool:
        if self.landed:
            return False
        self._set_mode(Mode.LAND)
        self.target = self._stop_point()
        self._phase = "descend"
        return True

    def rtl(self) -> bool:
        if self.landed:
            return False
        self._set_mode(Mode.RTL)
        self._phase = "climb"
        self._rtl_home = self.rtl_destination()
        return True

    def rtl_destination(self) -> np.ndarray:
        """Where RTL lands: the nearest of home (the launch point) and the rally points (PX4 RTL_TYPE 0), ENU x-y."""
        best = self.launch_xy.copy()
        for r in self.rally_points:
            if np.linalg.norm(r[:2] - self.pos[:2]) < np.linalg.norm(best - self.pos[:2]):
                best = np.asarray(r[:2], dtype=float)
        return best

    def goto(self, target: np.ndarray, yaw: float | None) -> bool:
        if not self.armed:
            return False
        self._set_mode(Mode.HOLD)
        self.target, self.target_yaw = np.asarray(target, dtype=float), yaw
        self.landed = False
        return True

    def start_mission(self) -> bool:
        if not self.items:
            return False
        if self.complete:  # restart a finished mission from the top
            self.seq, self.complete = 0, False
        self._set_mode(Mode.MISSION)
        self.started = True
        self._enter_item()
        return True

    def set_mode(self, mode: Mode) -> bool:
        return {
            Mode.HOLD: self.hold, Mode.POSCTL: self._posctl, Mode.MISSION: self.start_mission, Mode.RTL: self.rtl,
            Mode.LAND: self.land, Mode.TAKEOFF: lambda: self.takeoff(None), Mode.OFFBOARD: self.start_offboard,
            Mode.ORBIT: lambda: False, Mode.ALTCTL: self._altctl, Mode.FOLLOW: self.start_follow,
        }[mode]()

    def start_follow(self) -> bool:
        """AUTO.FOLLOW_TARGET: only in the air (a target that was never heard: hold where it is)."""
        if not self.armed or self.landed:
            return False
        if self.follow is not None:
            self.follow.reset()
        self._set_mode(Mode.FOLLOW)
        self.target, self.target_yaw = self._stop_point(), None
        return True

    def _altctl(self) -> bool:
        self.hold()
        self._set_mode(Mode.ALTCTL)
        return True

    def start_offboard(self) -> bool:
        """Switch to OFFBOARD (the caller checked the setpoint stream is alive)."""
        if self.offboard_setpoint is None:
            return False
        self._set_mode(Mode.OFFBOARD)
        self.target, self.target_yaw = self._stop_point(), None
        return True

    def start_orbit(self, orbit: Orbit) -> bool:
        if not self.armed or self.landed:
            return False
        orbit.initial_yaw = self.yaw
        self.orbit = orbit
        self._set_mode(Mode.ORBIT)
        return True

    def _posctl(self) -> bool:
        self.hold()
        self._set_mode(Mode.POSCTL)
        return True

    def set_current(self, seq: int) -> bool:
        """Jump to item ``seq`` (ends a dwell early when seq is the next item)."""
        if not 0 <= seq < len(self.items):
            return False
        self.seq, self.complete = seq, False
        if self.mode is Mode.MISSION:
            self._enter_item()
        return True

    def replace_mission(self, items: list[MissionItem]) -> None:
        """A new mission was uploaded: an active mission continues with the new one from item 0."""
        self.items = list(items)
        self.seq, self.complete = 0, False
        self.limits = self.base_limits
        if self.mode is Mode.MISSION:
            if self.items:
                self._enter_item()
            else:
                self.hold()
                self.started = False
        else:
            self.started = False

    # -- mission execution ---------------------------------------------------------------------
    def _enter_item(self) -> None:
        self._phase = "go"
        if self.seq >= len(self.items):
            return
        item = self.items[self.seq]
        self.target_yaw = None
        if item.command == M.MAV_CMD_NAV_TAKEOFF:
            tgt = self.item_target(item)
            self.target = np.array([self.pos[0], self.pos[1], tgt[2]])
            if self.armed:
                self.landed = False
        elif item.command in (M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LOITER_TIME):
            self.target = self.item_target(item)
            if item.command == M.MAV_CMD_NAV_WAYPOINT and math.isfinite(item.param4):
                self.target_yaw = yaw_ned_to_enu(math.radians(item.param4))
            if self.armed:
                self.landed = False
        elif item.command == M.MAV_CMD_NAV_LAND:
            tgt = self.item_target(item) if (item.x or item.y) else self.pos.copy()
            self.target = np.array([tgt[0], tgt[1], self.pos[2]])
        elif item.command == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self._phase = "climb"
            self._rtl_home = self.rtl_destination()
        elif item.command == M.MAV_CMD_NAV_LOITER_UNLIM:
            self.target = self.item_target(item)
            self._phase = "loiter"  # holds there until the mission is changed or another mode commanded
        elif item.command == M.MAV_CMD_NAV_DELAY:
            self.target = self._stop_point()
            self._phase = "hold"
            self._hold_until = self._t + max(item.param1, 0.0)
        elif item.command == M.MAV_CMD_DO_CHANGE_SPEED:
            if math.isfinite(item.param2) and item.param2 > 0:
                self.limits = self.limits.with_speed_xy(item.param2)
            self._phase = "done"
        else:  # DO items that do not move the vehicle (camera, gimbal, ROI): done at once
            self._phase = "done"

    def _advance(self) -> None:
        self.events.append(("reached", self.seq))
        if self.seq + 1 < len(self.items):
            self.seq += 1
            self._enter_item()
        else:
            self.complete = True
            self.events.append(("text", "Mission finished"))
            if self.in_air:
                self.target, self.target_yaw = self._stop_point(), None
                self._set_mode(Mode.HOLD)

    def _arrived(self) -> bool:
        return motion.arrived(self.pos, self.vel, self.target, self.p.acceptance_radius)

    def _mission_step(self) -> None:
        if self.complete or self.seq >= len(self.items) or not self.armed:
            return
        item = self.items[self.seq]
        cmd = item.command
        if self._phase == "done":
            self._advance()
        elif self._phase == "loiter":
            pass
        elif cmd == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            if self._rtl_step():
                self._advance()
        elif cmd == M.MAV_CMD_NAV_LAND:
            if self._phase == "go" and self._arrived():
                self._phase = "descend"
            if self._phase == "descend" and self._descend_step():
                self._advance()
        elif self._phase == "hold":
            if self._t >= self._hold_until:
                self._advance()
        elif self._passing(item):
            self._advance()
        elif self._arrived() and self._yaw_done():
            hold = item.param1 if cmd in (M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LOITER_TIME) else 0.0
            if hold > 0:
                self.events.append(("text", f"Holding {hold:.1f} s at item {self.seq}"))
                self._phase, self._hold_until = "hold", self._t + hold
            else:
                self._advance()

    def _passing(self, item: MissionItem) -> bool:
        """A via point (waypoint, no hold, another waypoint next) is passed without stopping."""
        if item.command != M.MAV_CMD_NAV_WAYPOINT or item.param1 > 0 or self.seq + 1 >= len(self.items):
            return False
        if self.items[self.seq + 1].command != M.MAV_CMD_NAV_WAYPOINT:
            return False
        return float(np.linalg.norm(self.target - self.pos)) <= max(self.p.pass_radius, self.p.acceptance_radius)

    def _yaw_done(self) -> bool:
        return self.target_yaw is None or abs(math.remainder(self.target_yaw - self.yaw, 2 * math.pi)) < 0.02

    def _rtl_step(self) -> bool:
        """Climb to the RTL altitude, fly home, land. True once landed."""
        if self._phase in ("go", "climb"):
            self._phase = "climb"
            self.target = np.array([self.pos[0], self.pos[1], max(self.pos[2], self.p.rtl_alt)])
            if self._arrived():
                self._phase = "return"
        if self._phase == "return":
            self.target = np.array([self._rtl_home[0], self._rtl_home[1], self.target[2]])
            if self._arrived():
                self._phase = "descend"
        if self._phase == "descend":
            return self._descend_step()
        return False

    def _descend_step(self) -> bool:
        """Descend at land speed to the ground; True when touched down."""
        self.target = np.array([self.target[0], self.target[1], 0.0])
        if self.pos[2] <= 0.02 and abs(self.vel[2]) < 0.05:
            self.pos[2], self.vel[:] = 0.0, 0.0
            if not self.landed:
                self.landed = True
                self._landed_at = self._t
                self.events.append(("text", "Landing detected"))
            return True
        return False

    # -- the fixed step -------------------------------------------------------------------------
    def step(self, t: float, dt: float) -> float:
        """Advance to sim time ``t + dt``; returns the distance flown (for the odometry)."""
        self._t = t
        attitude, self.attitude = self.attitude, None  # kept only while attitude offboard flies
        if self.armed and not self.landed:
            if self.mode is Mode.MISSION:
                self._mission_step()
            elif self.mode is Mode.TAKEOFF and self._arrived():
                self.events.append(("text", "Takeoff complete"))
                self.hold()
            elif self.mode is Mode.RTL:
                self._rtl_step()
            elif self.mode is Mode.LAND:
                self._descend_step()
            elif self.mode is Mode.ORBIT:
                return self._orbit_step(dt)
            elif self.mode is Mode.FOLLOW and self.follow is not None:
                self.target, self.target_yaw = self.follow.step(self.pos, dt)
        if self.landed and self.armed and self._landed_at is not None:
            if t - self._landed_at >= self.p.disarm_after_land_s:
                self.disarm()
                if self.mode is not Mode.OFFBOARD:  # PX4 stays in offboard after the auto-disarm
                    self._set_mode(Mode.HOLD)
                self.target = self.pos.copy()
        if self.mode is Mode.OFFBOARD and self.armed and self.offboard_setpoint is not None:
            if self.offboard_setpoint.attitude is not None:
                return self._attitude_step(attitude, dt)
            return self._offboard_step(dt)
        if self.mode in MANUAL_MODES and self.armed and self.manual is not None and self.manual.count:
            return self._manual_step(dt)
        if not self.armed or self.landed:
            self.accel[:] = 0
            return 0.0
        limits = self.limits
        if self.landing:
            limits = dataclasses.replace(limits, max_speed_down=self.p.land_speed)
        old = self.pos
        old_vel = self.vel
        self.pos, self.vel, self.yaw = motion.step(self.pos, self.vel, self.yaw, self.target, self.target_yaw,
                                                   limits, dt)
        self.accel = (self.vel - old_vel) / dt
        return float(np.linalg.norm(self.pos - old))

    # -- offboard and orbit ----------------------------------------------------------------------
    def _offboard_step(self, dt: float) -> float:
        """Track the offboard setpoint: position (with a velocity feed-forward ignored) or velocity.
        Takes off when the setpoint asks to climb; lands (and auto-disarms) when it asks for the ground."""
        from vehicle_sim.offboard import velocity_step

        sp = self.offboard_setpoint
        wants_up = (sp.pos is not None and sp.pos[2] > 0.1) or (sp.pos is None and sp.vel[2] > 0.05)
        if self.landed:
            if not wants_up:
                self.accel[:] = 0
                return 0.0
            self.landed, self._landed_at = False, None
        old, old_vel = self.pos, self.vel
        if sp.pos is not None:
            self.target = np.array([sp.pos[0], sp.pos[1], max(sp.pos[2], 0.0)])
            yaw_target = sp.yaw
            if yaw_target is None and sp.yaw_rate is not None:
                yaw_target = self.yaw + sp.yaw_rate * dt
            self.pos, self.vel, self.yaw = motion.step(self.pos, self.vel, self.yaw, self.target, yaw_target,
                                                       self.limits, dt)
        else:
            self.pos, self.vel, self.yaw = velocity_step(self.pos, self.vel, self.yaw, sp.vel, sp.yaw, sp.yaw_rate,
                                                         self.limits, dt)
        self.accel = (self.vel - old_vel) / dt
        if self.pos[2] <= 0.02 and not wants_up and abs(self.vel[2]) < 0.05:
            self.pos[2], self.vel[:] = 0.0, 0.0
            self.landed, self._landed_at = True, self._t
            self.events.append(("text", "Landing detected"))
        return float(np.linalg.norm(self.pos - old))

    def _attitude_step(self, attitude: tuple[float, float, float] | None, dt: float) -> float:
        """Fly an attitude (or body-rate) and thrust setpoint (``offboard.attitude_step``); lifts off once the
        thrust overcomes gravity, lands when it sets the vehicle down."""
        from vehicle_sim.offboard import attitude_step, lifts_off

        target = self.offboard_setpoint.attitude
        yaw_ned = math.pi / 2 - self.yaw
        up = lifts_off(target, self.p.hover_thrust)
        if self.landed:
            self.attitude = (0.0, 0.0, yaw_ned)
            if not up:
                self.accel[:] = 0
                return 0.0
            self.landed, self._landed_at = False, None
        old, old_vel = self.pos, self.vel
        self.pos, self.vel, self.attitude = attitude_step(self.pos, self.vel, attitude or (0.0, 0.0, yaw_ned),
                                                          target, self.p.hover_thrust, dt)
        self.yaw = yaw_ned_to_enu(self.attitude[2])
        self.accel = (self.vel - old_vel) / dt
        self.target, self.target_yaw = self.pos.copy(), None  # a switch to an auto mode holds here
        if self.pos[2] <= 0.0 and not up:
            self.landed, self._landed_at = True, self._t
            self.attitude = (0.0, 0.0, self.attitude[2])
            self.events.append(("text", "Landing detected"))
        return float(np.linalg.norm(self.pos - old))

    def _manual_step(self, dt: float) -> float:
        """Fly the virtual sticks (``manual_control``): velocities in POSCTL/ALTCTL; throttle up lifts off."""
        from vehicle_sim.manual_control import VEL_MANUAL, command
        from vehicle_sim.offboard import velocity_step

        s = self.manual.sticks
        climbing = s is not None and s.throttle > 0
        if self.landed:
            if not climbing:
                self.accel[:] = 0
                return 0.0
            self.landed, self._landed_at = False, None
        v, yaw_rate = command(s, self.yaw, self.vel, self.limits.max_speed_up, self.limits.max_speed_down,
                              self.mode is Mode.POSCTL, dt)
        old, old_vel = self.pos, self.vel
        self.pos, self.vel, self.yaw = velocity_step(self.pos, self.vel, self.yaw, v, None, yaw_rate,
                                                     self.limits.with_speed_xy(VEL_MANUAL), dt)
        self.accel = (self.vel - old_vel) / dt
        self.target, self.target_yaw = self.pos.copy(), None  # a switch to an auto mode holds here
        if self.pos[2] <= 0.02 and not climbing and abs(self.vel[2]) < 0.05:
            self.pos[2], self.vel[:] = 0.0, 0.0
            self.landed, self._landed_at = True, self._t
            self.events.append(("text", "Landing detected"))
        return float(np.linalg.norm(self.pos - old))

    def _orbit_step(self, dt: float) -> float:
        """Fly to the nearest point of the circle, then around it at the commanded speed (accelerating
        at the horizontal limit), yaw per the commanded behaviour."""
        o = self.orbit
        old, old_vel = self.pos, self.vel
        rel = self.pos[:2] - o.center[:2]
        if not o.circling:
            ang = math.atan2(rel[1], rel[0]) if np.linalg.norm(rel) > 1e-6 else 0.0
            entry = np.array([o.center[0] + o.radius * math.cos(ang), o.center[1] + o.radius * math.sin(ang),
                              o.center[2]])
            yaw = math.atan2(o.center[1] - self.pos[1], o.center[0] - self.pos[0]) if o.yaw_behaviour == 0 else None
            self.target = entry
            self.pos, self.vel, self.yaw = motion.step(self.pos, self.vel, self.yaw, entry, yaw, self.limits, dt)
            if motion.arrived(self.pos, self.vel, entry, max(self.p.acceptance_radius, 0.3), 0.3):
                o.circling, o.angle = True, ang
                self.events.append(("text", f"Orbit: circling r={o.radius:.1f} m at {o.speed:.1f} m/s"))
        else:
            v = min(o.speed, self.limits.max_speed_xy)
            o.tangential = min(v, o.tangential + self.limits.max_accel * dt)
            dang = o.direction * o.tangential / o.radius * dt
            o.angle = wrap(o.angle + dang)
            o.swept += abs(dang)
            c, s = math.cos(o.angle), math.sin(o.angle)
            new = np.array([o.center[0] + o.radius * c, o.center[1] + o.radius * s, o.center[2]])
            self.vel = np.array([-s, c, 0.0]) * o.direction * o.tangential
            self.pos = new
            self.target = new
            lim = self.limits.max_yaw_rate * dt
            want = {0: o.angle + math.pi, 1: o.initial_yaw, 3: o.angle + o.direction * math.pi / 2}.get(o.yaw_behaviour)
            if want is not None:
                self.yaw = wrap(self.yaw + max(-lim, min(lim, wrap(want - self.yaw))))
            if o.swept >= 2 * math.pi * o.orbits:
                self.events.append(("text", "Orbit: done"))
                self.hold()
        self.accel = (self.vel - old_vel) / dt
        return float(np.linalg.norm(self.pos - old))


def wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi
