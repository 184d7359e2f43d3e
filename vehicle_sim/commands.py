"""COMMAND_LONG / COMMAND_INT handling: each command is decoded once into a ``Command``, executed on the
navigator (or the vehicle's services) and answered with COMMAND_ACK.

PX4-flavoured, since that is the autopilot type announced: arm 400, takeoff 22, land 21, RTL 20,
hold 17 or DO_SET_MODE AUTO.LOITER, set mode 176 (PX4 main/sub modes), mission start 300 or
DO_SET_MODE AUTO.MISSION, set current item 224, reposition/go-to 192, change speed 178, orbit 34
(DO_ORBIT), OFFBOARD through DO_SET_MODE (only with a live setpoint stream), plus the
message services MAVSDK uses (SET_MESSAGE_INTERVAL 511, REQUEST_MESSAGE 512, capabilities 520), and sensor
calibration 241 (PREFLIGHT_CALIBRATION: ``calibration``).
Every command is answered (``answer``): unknown commands get MAV_RESULT_UNSUPPORTED; bad parameters
MAV_RESULT_DENIED, and a parameter that must be a number but is NaN or infinite is named: its index
(1-7) goes in the ACK's ``result_param2`` and the reason in a STATUSTEXT. NaN keeps its MAVLink meaning
("unset": default or keep) only where the command defines it. A failure inside a command is
MAV_RESULT_FAILED, never silence.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from pymavlink.dialects.v20 import common as M

from radseek.coordinates import Home, geodetic_to_enu, yaw_ned_to_enu
from vehicle_sim.geofence import Geofence
from vehicle_sim.navigator import Mode, Navigator, Orbit, mode_from_px4

log = logging.getLogger(__name__)
#: SET_MESSAGE_INTERVAL's accepted intervals (us): at most 1 kHz, at least one message a minute
MIN_INTERVAL_US = 1_000.0
MAX_INTERVAL_US = 60_000_000.0
FORCE_MAGIC = 21196


@dataclass(frozen=True)
class Command:
    command: int
    params: tuple[float, float, float, float]
    lat: float  # deg or nan
    lon: float
    alt: float  # m, meaning per frame
    frame: int  # MAV_FRAME_GLOBAL (AMSL) for COMMAND_LONG

    def param(self, index: int) -> float:
        """MAVLink param ``index`` (1-7); 5-7 are lat, lon, alt."""
        return (*self.params, self.lat, self.lon, self.alt)[index - 1]

    @classmethod
    def from_msg(cls, msg) -> Command:
        p = (float(msg.param1), float(msg.param2), float(msg.param3), float(msg.param4))
        if msg.get_type() == "COMMAND_INT":
            glob = msg.x != 0 or msg.y != 0
            lat = msg.x / 1e7 if glob else math.nan
            lon = msg.y / 1e7 if glob else math.nan
            return cls(int(msg.command), p, lat, lon, float(msg.z), int(msg.frame))
        return cls(int(msg.command), p, float(msg.param5), float(msg.param6), float(msg.param7),
                   M.MAV_FRAME_GLOBAL)


class Refused(Exception):
    """A command refused (DENIED) for a reason worth telling the operator (STATUSTEXT)."""


class InvalidParam(ValueError):
    """A parameter the command cannot use; ``index`` is its MAVLink number (1-7)."""

    def __init__(self, index: int, why: str):
        super().__init__(f"param{index} {why}")
        self.index = index


def _required(cmd: Command, index: int) -> float:
    v = cmd.param(index)
    if not math.isfinite(v):
        raise InvalidParam(index, f"is {v}, must be a finite number")
    return v


def _optional(cmd: Command, index: int) -> float | None:
    """NaN means unset (None); infinity is refused."""
    v = cmd.param(index)
    if math.isnan(v):
        return None
    if not math.isfinite(v):
        raise InvalidParam(index, f"is {v}, must be a finite number or NaN (unset)")
    return v


@dataclass(frozen=True)
class Answer:
    result: int  # MAV_RESULT
    extra: list  # messages to send after the ACK
    param: int = 0  # the offending param (1-7), for result_param2
    reason: str = ""  # why it was refused, for the log and a STATUSTEXT


def answer(cmd: Command, svc: Services) -> Answer:
    """``execute`` made total: whatever the parameters, there is a result to ACK."""
    try:
        result, extra = execute(cmd, svc)
        return Answer(result, [m for m in extra if m is not None])
    except InvalidParam as exc:
        return Answer(M.MAV_RESULT_DENIED, [], exc.index, str(exc))
    except Refused as exc:
        return Answer(M.MAV_RESULT_DENIED, [], 0, str(exc))
    except Exception as exc:  # noqa: BLE001 - a command must never go unanswered
        log.exception("command %d %s failed", cmd.command, cmd.params)
        return Answer(M.MAV_RESULT_FAILED, [], 0, f"{type(exc).__name__}: {exc}")


class Services(Protocol):
    """What commands need from the vehicle besides the navigator."""

    nav: Navigator
    home: Home
    fence: Geofence

    def message_by_id(self, msg_id: int):  # the message, or None if not offered
        ...

    def set_message_interval(self, msg_id: int, interval_us: float) -> bool: ...

    def offboard_alive(self) -> bool:  # a setpoint stream is on (offboard.OffboardStream.alive)
        ...

    def inject_failure(self, unit: int, ftype: int, instance: int) -> int:  # MAV_RESULT (failure_injection)
        ...

    def takeoff_note(self, text: str) -> None:  # tell the operator (STATUSTEXT)
        ...

    def calibrate(self, params: tuple[float, ...]) -> int:  # MAV_RESULT (calibration)
        ...


def _alt_to_enu_z(cmd: Command, home: Home) -> float:
    rel = cmd.frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
    return cmd.alt if rel else cmd.alt - home.alt_m


def execute(cmd: Command, svc: Services) -> tuple[int, list]:
    """Run one command; returns (MAV_RESULT, extra messages to send after the ACK). Raises
    ``InvalidParam`` for a parameter it cannot use (``answer`` turns that into DENIED)."""
    nav, c = svc.nav, cmd.command
    ok = M.MAV_RESULT_ACCEPTED
    denied = M.MAV_RESULT_DENIED
    if c == M.MAV_CMD_COMPONENT_ARM_DISARM:
        p1 = _required(cmd, 1)
        if p1 == 1:
            return (ok if nav.arm() else denied), []
        if p1 == 0:
            return (ok if nav.disarm(force=cmd.param(2) == FORCE_MAGIC) else denied), []
        return denied, []
    if c == M.MAV_CMD_NAV_TAKEOFF:
        if not nav.armed:
            return M.MAV_RESULT_TEMPORARILY_REJECTED, []
        alt = _alt_to_enu_z(cmd, svc.home) if _optional(cmd, 7) is not None else None
        if alt is not None and alt < nav.p.takeoff_alt:
            # PX4 (navigator/takeoff.cpp): an altitude below home + MIS_TAKEOFF_ALT is raised to it and the command
            # accepted; what MAVProxy's `takeoff 5` sends (5 m in param7, read as AMSL) takes off to MIS_TAKEOFF_ALT
            svc.takeoff_note(f"Using minimum takeoff altitude: {nav.p.takeoff_alt:.2f} m")
            alt = nav.p.takeoff_alt
        if alt is not None and not svc.fence.contains(np.array([nav.pos[0], nav.pos[1], alt])):
            return denied, []
        return (ok if nav.takeoff(alt) else denied), []
    if c == M.MAV_CMD_NAV_LAND:
        return (ok if nav.land() else denied), []
    if c == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
        return (ok if nav.rtl() else denied), []
    if c == M.MAV_CMD_NAV_LOITER_UNLIM:
        return (ok if nav.hold() else denied), []
    if c == M.MAV_CMD_DO_SET_MODE:
        base, main, sub = _required(cmd, 1), _required(cmd, 2), _required(cmd, 3)
        if not (int(base) & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED):
            return denied, []
        mode = mode_from_px4(int(main), int(sub))
        if mode is None:
            return M.MAV_RESULT_UNSUPPORTED, []
        if mode is Mode.OFFBOARD and not svc.offboard_alive():
            raise Refused("offboard needs a setpoint stream first (SET_POSITION_TARGET_*, SET_ATTITUDE_TARGET; > 1 Hz)")
        return (ok if nav.set_mode(mode) else denied), []
    if c == M.MAV_CMD_DO_ORBIT:
        return _orbit(cmd, svc), []
    if c == M.MAV_CMD_MISSION_START:
        first = _optional(cmd, 1)  # NaN: from the current item
        if first is not None and first > 0 and not nav.set_current(int(first)):
            return denied, []
        return (ok if nav.start_mission() else denied), []
    if c == M.MAV_CMD_DO_SET_MISSION_CURRENT:
        return (ok if nav.set_current(int(_required(cmd, 1))) else denied), []
    if c == M.MAV_CMD_DO_REPOSITION:
        return _reposition(cmd, svc), []
    if c == M.MAV_CMD_DO_CHANGE_SPEED:
        speed = _required(cmd, 2)
        if not 0 < speed <= 20:
            return denied, []
        nav.limits = nav.limits.with_speed_xy(speed)
        return ok, []
    if c == M.MAV_CMD_SET_MESSAGE_INTERVAL:
        p1, p2 = _required(cmd, 1), _required(cmd, 2)
        # MAVLink: -1 disables, 0 restores the default, > 0 is the interval in us; anything else (-1e30, a
        # microsecond, a day) is no interval a stream can keep
        if not (p2 in (-1.0, 0.0) or MIN_INTERVAL_US <= p2 <= MAX_INTERVAL_US):
            log.info("SET_MESSAGE_INTERVAL %g us for message %d denied (-1, 0 or %g..%g us)", p2, int(p1),
                     MIN_INTERVAL_US, MAX_INTERVAL_US)
            return M.MAV_RESULT_DENIED, []
        return (ok if svc.set_message_interval(int(p1), p2) else M.MAV_RESULT_UNSUPPORTED), []
    if c == M.MAV_CMD_REQUEST_MESSAGE:
        msg = svc.message_by_id(int(_required(cmd, 1)))
        return (ok, [msg]) if msg is not None else (M.MAV_RESULT_UNSUPPORTED, [])
    if c == M.MAV_CMD_INJECT_FAILURE:
        return svc.inject_failure(int(_required(cmd, 1)), int(_required(cmd, 2)), int(_required(cmd, 3))), []
    if c == M.MAV_CMD_PREFLIGHT_CALIBRATION:
        return svc.calibrate(tuple(cmd.param(i) for i in range(1, 8))), []
    if c == M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
        return ok, [svc.message_by_id(M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)]
    log.info("command %d unsupported", c)
    return M.MAV_RESULT_UNSUPPORTED, []


def _reposition(cmd: Command, svc: Services) -> int:
    nav = svc.nav
    if not nav.armed:
        return M.MAV_RESULT_TEMPORARILY_REJECTED
    target = nav.pos.copy()
    lat, lon, alt, yaw_deg = _optional(cmd, 5), _optional(cmd, 6), _optional(cmd, 7), _optional(cmd, 4)
    if lat is not None and lon is not None:
        if not (-90 <= cmd.lat <= 90 and -180 <= cmd.lon <= 180):
            return M.MAV_RESULT_DENIED
        target[:2] = geodetic_to_enu(svc.home, cmd.lat, cmd.lon, svc.home.alt_m)[:2]
    if alt is not None:
        target[2] = _alt_to_enu_z(cmd, svc.home)
    if not svc.fence.contains(target):
        log.warning("reposition to %s outside the geofence: denied", np.round(target, 2))
        return M.MAV_RESULT_DENIED
    speed = cmd.params[0]
    if math.isfinite(speed) and 0 < speed <= 20:
        nav.limits = nav.limits.with_speed_xy(speed)
    yaw = yaw_ned_to_enu(math.radians(yaw_deg)) if yaw_deg is not None else None
    return M.MAV_RESULT_ACCEPTED if nav.goto(target, yaw) else M.MAV_RESULT_DENIED


ORBIT_MAX_RADIUS = 1000.0  # m, PX4's FlightTaskOrbit limit
ORBIT_DEFAULT_RADIUS, ORBIT_DEFAULT_SPEED = 10.0, 1.0  # m, m/s when NaN (PX4's defaults)


def _orbit(cmd: Command, svc: Services) -> int:
    """MAV_CMD_DO_ORBIT: p1 radius (m; positive clockwise, negative counter-clockwise; NaN default),
    p2 tangential speed (m/s; NaN default), p3 yaw behaviour (ORBIT_YAW_BEHAVIOUR; NaN = front to
    centre), p4 orbits (NaN/0 = forever), centre lat/lon (NaN = here), altitude (NaN = current). As in PX4
    the altitude is AMSL whatever the frame (MAVSDK's do_orbit sends AMSL in a relative-frame COMMAND_INT).
    Only in the air; the whole circle must be inside the geofence."""
    nav = svc.nav
    if not nav.armed or nav.landed:
        raise Refused("orbit needs the vehicle in the air")
    radius = _optional(cmd, 1)
    radius = ORBIT_DEFAULT_RADIUS if radius is None else radius
    if not 1.0 <= abs(radius) <= ORBIT_MAX_RADIUS:
        raise InvalidParam(1, f"radius {radius} m must be within 1-{ORBIT_MAX_RADIUS:g} m in magnitude")
    speed = _optional(cmd, 2)
    speed = ORBIT_DEFAULT_SPEED if speed is None else abs(speed)
    if not 0 < speed <= 20:
        raise InvalidParam(2, f"speed {speed} m/s must be in (0, 20]")
    behaviour = _optional(cmd, 3)
    behaviour = 0 if behaviour is None else int(behaviour)
    if behaviour not in (0, 1, 2, 3, 4):
        raise InvalidParam(3, f"yaw behaviour {behaviour} is not an ORBIT_YAW_BEHAVIOUR")
    orbits = _optional(cmd, 4)
    orbits = math.inf if orbits is None or orbits <= 0 else orbits
    center = nav.pos.copy()
    lat, lon, alt = _optional(cmd, 5), _optional(cmd, 6), _optional(cmd, 7)
    if lat is not None and lon is not None:
        if not (-90 <= lat <= 90 and -180 <= lon <= 180):
            raise InvalidParam(5 if not -90 <= lat <= 90 else 6, "is not a valid latitude/longitude")
        center[:2] = geodetic_to_enu(svc.home, lat, lon, svc.home.alt_m)[:2]
    if alt is not None:
        center[2] = alt - svc.home.alt_m
    r = abs(radius)
    for dx, dy in ((r, 0), (-r, 0), (0, r), (0, -r), (0, 0)):
        if not svc.fence.contains(center + np.array([dx, dy, 0.0])):
            raise Refused(f"orbit of radius {r:g} m about ({center[0]:.1f}, {center[1]:.1f}, {center[2]:.1f}) m "
                          "leaves the geofence")
    orbit = Orbit(center, r, -1.0 if radius > 0 else 1.0, speed, behaviour, orbits)
    return M.MAV_RESULT_ACCEPTED if nav.start_orbit(orbit) else M.MAV_RESULT_DENIED


def set_mode_message(msg, nav: Navigator) -> int:
    """The legacy SET_MODE message: PX4 custom mode in ``custom_mode``."""
    if not (msg.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED):
        return M.MAV_RESULT_DENIED
    main, sub = (msg.custom_mode >> 16) & 0xFF, (msg.custom_mode >> 24) & 0xFF
    mode = mode_from_px4(main, sub)
    if mode is None:
        return M.MAV_RESULT_UNSUPPORTED
    return M.MAV_RESULT_ACCEPTED if nav.set_mode(mode) else M.MAV_RESULT_DENIED

