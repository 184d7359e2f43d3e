"""The mock autopilot's loop: steps the simulation in fixed sim steps on the one clock, answers
MAVLink on every endpoint, emits telemetry, and publishes clock / true pose / estimated pose on zenoh.

Zenoh never blocks MAVLink: the session is opened in a background thread and publishing starts when
it is up (a missing router only means nobody sees the zenoh topics yet). A router that refuses the
vehicle's credentials stops it (``Vehicle.zenoh_refused``): a vehicle its stack cannot hear must not fly on.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as M

from radseek.coordinates import Home, geodetic_to_enu, yaw_enu_to_ned
from vehicle_sim import battery as battery_model
from vehicle_sim import commands, offboard, telemetry
from vehicle_sim import imu as imu_model
from vehicle_sim.calibration import Calibrations
from vehicle_sim.failsafe import FailsafeParams
from vehicle_sim.failure_injection import Failures
from vehicle_sim.flight_log import FlightLog
from vehicle_sim.follow_target import FollowTarget
from vehicle_sim.geofence import Geofence, zones_from_items
from vehicle_sim.imu import ImuStream, tilt
from vehicle_sim.link import Endpoint, Link
from vehicle_sim.log_transfer import LogServer
from vehicle_sim.manual_control import ManualControl, sticks_from_msg
from vehicle_sim.mavftp import FtpServer, VirtualFile, VirtualFs
from vehicle_sim.mavlink_shell import MavlinkShell, Pxh, ShellStatus
from vehicle_sim.mission_protocol import GLOBAL_FRAMES, MissionItem, MissionProtocol, basic_validate
from vehicle_sim.motion import MotionLimits
from vehicle_sim.navigator import MANUAL_MODES, Mode, NavParams
from vehicle_sim.odometry import OdometryParams
from vehicle_sim.params import INT32, Param, ParamTable
from vehicle_sim.px4_logger import Px4Logger
from vehicle_sim.sim_vehicle import SimVehicle

log = logging.getLogger(__name__)

MISSION_MSGS = {"MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_REQUEST_LIST", "MISSION_REQUEST_INT",
                "MISSION_REQUEST", "MISSION_CLEAR_ALL", "MISSION_ACK"}
PARAM_MSGS = {"PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"}
SETPOINT_MSGS = {"SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT"}
LOG_MSGS = {"LOG_REQUEST_LIST", "LOG_REQUEST_DATA", "LOG_REQUEST_END", "LOG_ERASE"}
LOG_DIR = "/fs/microsd/log"  # PX4's log folder, as its FTP server shows it
BULK_PER_TURN = 64  # file-transfer packets sent per loop turn (a burst must not overflow a client's socket)


@dataclass
class VehicleConfig:
    """Everything ``radseek vehicle`` can set (units in names/comments)."""

    bind_host: str = "127.0.0.1"
    remote_host: str = "127.0.0.1"
    api_port: int = 14540  # MAVSDK / offboard API (PX4 SITL: the vehicle sends here)
    gcs_port: int = 14550  # QGroundControl / MAVProxy
    api_local_port: int = 14580  # where the vehicle's API socket is bound (0 = any free port)
    gcs_local_port: int = 18570
    sysid: int = 1
    compid: int = 1  # must be 1: MAVSDK only takes component 1 as an autopilot
    speedup: float = 1.0  # sim s per wall s, (0, 1000]
    dt: float = 0.05  # s, fixed sim step, (0, 0.2]
    seed: int = 0
    imu_noise: bool = True  # PX4 SITL's IMU noise densities (vehicle_sim.imu.ImuNoise); False: noise-free readings
    home: Home = field(default_factory=Home)
    fence: Geofence = field(default_factory=Geofence)
    limits: MotionLimits = field(default_factory=MotionLimits)
    nav: NavParams = field(default_factory=NavParams)
    odometry: OdometryParams = field(default_factory=OdometryParams)
    battery: battery_model.BatteryParams = field(default_factory=battery_model.BatteryParams)
    failsafe: FailsafeParams = field(default_factory=FailsafeParams)
    signing_key: bytes | None = None
    drop_rate: float = 0.0
    zenoh: bool = True
    zenoh_config: str | None = None
    zenoh_connect: str = "tcp/127.0.0.1:7447"
    vehicle_name: str = "uav0"
    max_wall_hz: float = 20.0  # cap per telemetry message, Hz of wall time
    lockstep: bool = False  # hold sim time for the mission process (mission/lockstep), vehicle_sim.lockstep
    lockstep_timeout_s: float = 5.0  # wall s without a mission/lockstep message before lockstep is released
    #: m, local ENU: where the vehicle stands at start (its launch point, where RTL lands it, as PX4 sets its
    #: home where it arms). Several vehicles of a team share the frame origin (``home``) and start apart
    start_xy: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if not 0 < self.speedup <= 1000:
            raise ValueError(f"speedup {self.speedup} must be in (0, 1000]")
        if not 0 < self.dt <= 0.2:
            raise ValueError(f"dt {self.dt} must be in (0, 0.2]")


class _ZenohOut:
    """Publishers for sim/clock, sim/truth_pose and pose, opened in the background."""

    def __init__(self, cfg: VehicleConfig, gate=None, on_refused: Callable[[str], None] | None = None):
        self.cfg = cfg
        self._gate = gate  # vehicle_sim.lockstep.LockstepGate, fed from mission/lockstep
        self._on_refused = on_refused  # called with the one-line reason when the router refuses the session
        self.ready = False
        self._session = None
        self._closed = False
        self._thread = threading.Thread(target=self._open, name="zenoh-open", daemon=True)
        self._thread.start()

    def _open(self) -> None:
        from radseek import topics
        from radseek.simclock import ClockPublisher
        from radseek.zenoh_auth import CredentialsError
        from radseek.zenoh_session import RouterRefused, open_session, session_user

        try:
            user = None if self.cfg.zenoh_config else session_user("vehicle", self.cfg.vehicle_name)
            session = open_session(self.cfg.zenoh_config, self.cfg.zenoh_connect, user=user, wait_for_router_s=1e9)
        except (RouterRefused, CredentialsError, FileNotFoundError) as exc:  # no waiting mends these
            if self._on_refused is not None:
                self._on_refused(str(exc))
            return
        except Exception as exc:  # noqa: BLE001 - zenoh trouble must not stop the vehicle
            log.error("zenoh unavailable (%s): flying without zenoh topics", exc)
            return
        if self._closed:
            session.close()
            return
        name = self.cfg.vehicle_name
        self._clock = ClockPublisher(session, name, self.cfg.speedup)
        self._truth = topics.declare_publisher(session, topics.SIM_TRUTH_POSE, name)
        self._pose = topics.declare_publisher(session, topics.POSE, name)
        if self._gate is not None:
            self._lockstep = session.declare_subscriber(topics.key(topics.MISSION_LOCKSTEP, name),
                                                        self._gate.on_sample)
        self._topics = topics
        self._session = session
        self.ready = True
        log.info("zenoh connected: publishing radseek/%s/{sim/clock,sim/truth_pose,pose}", name)

    def publish(self, t: float, truth: tuple[np.ndarray, float], est: tuple[np.ndarray, float], var: np.ndarray,
                with_pose: bool) -> None:
        if not self.ready:
            return
        tp = self._topics
        try:  # poses first, the clock last: whoever sees the clock at t has every pose up to t
            p, yaw = truth
            self._truth.put(tp.TruthPose(t=t, x=float(p[0]), y=float(p[1]), z=float(max(p[2], 0.0)),
                                         yaw=float(yaw)).to_bytes())
            if with_pose:
                p, yaw = est
                self._pose.put(tp.Pose(t=t, x=float(p[0]), y=float(p[1]), z=float(p[2]), yaw=float(yaw),
                                       var_x=float(var[0]), var_y=float(var[1]), var_z=float(var[2]),
                                       var_yaw=float(var[3])).to_bytes())
            self._clock.publish(t)
        except Exception as exc:  # noqa: BLE001
            log.warning("zenoh publish failed: %s", exc)

    def close(self) -> None:
        self._closed = True
        if self._session is not None:
            self.ready = False
            try:
                self._session.close()
            except Exception:  # noqa: BLE001
                pass


class Vehicle(SimVehicle):
    """The simulated vehicle (``SimVehicle``) behind its MAVLink endpoints and zenoh topics."""

    def __init__(self, cfg: VehicleConfig):
        super().__init__(cfg)
        self.protocol = MissionProtocol(self._validate_item, sysid=cfg.sysid, compid=cfg.compid,
                                        validate_list=self._validate_list)
        self.offboard = offboard.OffboardStream()
        self.follow = self.nav.follow = FollowTarget(cfg.home, lambda p: self.fence.contains(p))
        self.manual = self.nav.manual = ManualControl()
        self.failures = Failures()
        self.calibrations = Calibrations()
        self._refused_sp: np.ndarray | None = None
        self._proto_ep: Endpoint | None = None
        self.link = Link(
            [("api", (cfg.bind_host, cfg.api_local_port), (cfg.remote_host, cfg.api_port)),
             ("gcs", (cfg.bind_host, cfg.gcs_local_port), (cfg.remote_host, cfg.gcs_port))],
            sysid=cfg.sysid, compid=cfg.compid, signing_key=cfg.signing_key, drop_rate=cfg.drop_rate,
            seed=cfg.seed, wall_time_s=time.time())
        self.params = self._make_params()
        noise = (imu_model.ImuNoise.seeded(cfg.seed, 0), imu_model.ImuNoise.seeded(cfg.seed, 1)) if cfg.imu_noise \
            else (None, None)
        self.imu = ImuStream(cfg.home, cfg.speedup, *noise)
        # two logs of one boot: the ULog PX4 writes (log 0 of the log protocol, as on PX4) and the telemetry log
        # of what the vehicle sent (.tlog, beside it in the log folder, by MAVLink FTP)
        self.flight_log = FlightLog()
        self.ulog = Px4Logger([(p.name, p.value, p.ptype == INT32) for p in self.params.params], cfg.sysid,
                              cfg.compid, cfg.battery.cells, cfg.battery.low_threshold,
                              cfg.battery.critical_threshold, boot_wall_s=self.flight_log.boot_wall_s)
        self._logged_params = {p.name: p.value for p in self.params.params}
        self.ulog.record(self.snapshot(), self._imu_now())
        self.link.tap = lambda msg, frame: self.flight_log.record(msg, frame, self.t)
        fs = VirtualFs()
        fs.add(f"{LOG_DIR}/{self.ulog.name}", VirtualFile(self.ulog.size, self.ulog.read))
        fs.add(f"{LOG_DIR}/{self.flight_log.name}", VirtualFile(self.flight_log.size, self.flight_log.read))
        self.ftp = FtpServer(fs)
        self.shell = MavlinkShell(Pxh(self.params, self._shell_status, self._shell_command))
        self.logs = LogServer(self.ulog)
        self._log_ep: Endpoint | None = None
        self._bulk: deque = deque()  # (message, endpoint) of file transfers, paced by flush_bulk
        self.scheduler = telemetry.Scheduler(cfg.speedup, cfg.max_wall_hz)
        self._text_id = 0
        self._stop = threading.Event()
        self.zenoh_refused: str | None = None  # why the zenoh session was refused (the vehicle then stops)
        self._zenoh: _ZenohOut | None = None
        self._last_pose_t = -1.0
        self._pose_every = max(1, round(0.1 / cfg.dt))  # steps between `pose` messages (10 Hz on the step grid)
        self._hold_until = math.inf  # lockstep: the sim time the vehicle holds at (a pose is published there)
        self.lockstep = None  # vehicle_sim.lockstep.LockstepGate while run() runs with cfg.lockstep
        self.stats = {"steps": 0, "commands": 0, "ignored": 0, "lockstep_pauses": 0, "lockstep_held_wall_s": 0.0}

    # -- parameters ------------------------------------------------------------------------------
    def _make_params(self) -> ParamTable:
        nav = self.nav

        def set_nav(name):
            def apply(v):
                nav.p = dataclasses.replace(nav.p, **{name: v})
            return apply

        def set_lim(name):
            def apply(v):
                nav.base_limits = dataclasses.replace(nav.base_limits, **{name: v})
                nav.limits = dataclasses.replace(nav.limits, **{name: v})
            return apply

        def set_fs(v):
            self.failsafe.params = dataclasses.replace(self.failsafe.params, link_loss_timeout_s=v)

        fp = self.follow.p

        def set_follow(name, conv=float):
            return lambda v: setattr(fp, name, conv(v))

        c = self.cfg
        return ParamTable([
            Param("MIS_TAKEOFF_ALT", c.nav.takeoff_alt, 0.5, 100, "m", set_nav("takeoff_alt")),
            Param("RTL_RETURN_ALT", c.nav.rtl_alt, 1, 120, "m", set_nav("rtl_alt")),
            Param("MPC_LAND_SPEED", c.nav.land_speed, 0.1, 3, "m/s", set_nav("land_speed")),
            Param("NAV_ACC_RAD", c.nav.acceptance_radius, 0.01, 10, "m", set_nav("acceptance_radius")),
            Param("MPC_XY_CRUISE", c.limits.max_speed_xy, 0.1, 20, "m/s", set_lim("max_speed_xy")),
            Param("MPC_ACC_HOR", c.limits.max_accel, 0.1, 10, "m/s^2", set_lim("max_accel")),
            Param("MPC_THR_HOVER", c.nav.hover_thrust, 0.1, 0.9, "", set_nav("hover_thrust")),
            Param("COM_DL_LOSS_T", c.failsafe.link_loss_timeout_s, 0.5, 600, "s", set_fs),
            Param("COM_OF_LOSS_T", self.offboard.loss_timeout_s, 0.1, 60, "s",
                  lambda v: setattr(self.offboard, "loss_timeout_s", v)),
            Param("BAT_LOW_THR", c.battery.low_threshold, 0, 1, "", None),
            Param("BAT_CRIT_THR", c.battery.critical_threshold, 0, 1, "", None),
            Param("SIM_SPEEDUP", c.speedup, c.speedup, c.speedup, "", None),  # read-only: fixed at start
            # FollowMe (PX4's follow_target_params.c; heights down to PX4's 1 m minimum safety altitude)
            Param("FLW_TGT_HT", fp.height, 1, 100, "m", set_follow("height")),
            Param("FLW_TGT_DST", fp.distance, 1, 100, "m", set_follow("distance")),
            Param("FLW_TGT_FA", fp.angle_deg, -180, 180, "deg", set_follow("angle_deg")),
            Param("FLW_TGT_RS", fp.responsiveness, 0, 1, "", set_follow("responsiveness")),
            Param("FLW_TGT_ALT_M", fp.alt_mode, 0, 2, "", set_follow("alt_mode", int), INT32),
            Param("FLW_TGT_MAX_VEL", fp.max_vel, 0, 20, "m/s", set_follow("max_vel")),
            Param("SYS_FAILURE_EN", 0, 0, 1, "", lambda v: setattr(self.failures, "enabled", bool(v)), INT32),
        ])

    # -- validation (mission items and go-to targets) -------------------------------------------
    def _validate_item(self, item: MissionItem) -> int:
        result = basic_validate(item)
        if result != M.MAV_MISSION_ACCEPTED or item.frame not in GLOBAL_FRAMES:
            return result
        if item.mission_type == M.MAV_MISSION_TYPE_FENCE:  # fence vertices: any valid lat/lon
            lat, lon = item.x / 1e7, item.y / 1e7
            if not -90 <= lat <= 90:
                return M.MAV_MISSION_INVALID_PARAM5_X
            if not -180 <= lon <= 180:
                return M.MAV_MISSION_INVALID_PARAM6_Y
            return M.MAV_MISSION_ACCEPTED
        if item.x == 0 and item.y == 0:  # "here": only the altitude matters
            p = np.array([0.0, 0.0, item.z if item.frame in (3, 6) else item.z - self.home.alt_m])
            p[:2] = [(self.fence.xmin + self.fence.xmax) / 2, (self.fence.ymin + self.fence.ymax) / 2]
        else:
            lat, lon = item.x / 1e7, item.y / 1e7
            if not (-90 <= lat <= 90):
                return M.MAV_MISSION_INVALID_PARAM5_X
            if not (-180 <= lon <= 180):
                return M.MAV_MISSION_INVALID_PARAM6_Y
            rel = item.frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
            p = geodetic_to_enu(self.home, lat, lon, item.z + self.home.alt_m if rel else item.z)
        if item.command == M.MAV_CMD_NAV_LAND:
            p[2] = self.fence.zmin  # a landing ends on the ground: its altitude field is not checked
        if item.command == M.MAV_CMD_DO_SET_ROI_LOCATION:
            return M.MAV_MISSION_ACCEPTED  # a point to look at, not to fly to
        axis = self.fence.violated_axis(p)
        if axis is not None:
            # ENU east is the longitude (param6, y), north the latitude (param5, x), up the altitude (param7)
            name = ("east (longitude, param6)", "north (latitude, param5)", "altitude (param7)")[axis]
            self.statustext(f"item {item.seq} outside the geofence on {name}: {np.round(p, 1).tolist()} m",
                            M.MAV_SEVERITY_WARNING)
            return (M.MAV_MISSION_INVALID_PARAM6_Y, M.MAV_MISSION_INVALID_PARAM5_X, M.MAV_MISSION_INVALID_PARAM7)[axis]
        why = self.fence.zone_violation(p)
        if why is not None:
            self.statustext(f"item {item.seq} {why}", M.MAV_SEVERITY_WARNING)
            return M.MAV_MISSION_DENIED
        return M.MAV_MISSION_ACCEPTED

    def _to_enu_xy(self, lat: float, lon: float) -> tuple[float, float]:
        p = geodetic_to_enu(self.home, lat, lon, self.home.alt_m)
        return float(p[0]), float(p[1])

    def _validate_list(self, items: list[MissionItem], mtype: int) -> int:
        """Whole-list checks: a fence's polygons must be complete; the home must stay usable."""
        if mtype == M.MAV_MISSION_TYPE_FENCE:
            try:
                zones_from_items(items, self._to_enu_xy)
            except ValueError as exc:
                self.statustext(f"fence refused: {exc}", M.MAV_SEVERITY_WARNING)
                return M.MAV_MISSION_INVALID_PARAM1
        return M.MAV_MISSION_ACCEPTED

    # -- services for commands -------------------------------------------------------------------
    def snapshot(self) -> telemetry.Snapshot:
        nav = self.nav
        if nav.landed:
            landed_state = M.MAV_LANDED_STATE_ON_GROUND
        elif nav.landing:
            landed_state = M.MAV_LANDED_STATE_LANDING
        elif nav.mode is Mode.TAKEOFF:
            landed_state = M.MAV_LANDED_STATE_TAKEOFF
        else:
            landed_state = M.MAV_LANDED_STATE_IN_AIR
        items = nav.items
        seq = min(nav.seq, max(len(items) - 1, 0))
        return telemetry.Snapshot(
            self.t, nav.pos, nav.vel, nav.accel, nav.yaw, self._yaw_rate, self.odo.var, nav.armed, nav.landed,
            landed_state, nav.mode, self.battery, battery_model.voltage(self.battery, self.cfg.battery), self.home,
            seq, len(items), nav.mission_state, self.failsafe_active, failures=frozenset(self.failures.active),
            tilt=None if nav.attitude is None else nav.attitude[:2])

    def message_by_id(self, msg_id: int):
        """The message REQUEST_MESSAGE asks for, or None if the vehicle does not offer it."""
        if msg_id == M.MAVLINK_MSG_ID_HIGHRES_IMU:
            return self._imu_now()
        name = telemetry.MSG_IDS.get(msg_id)
        return None if name is None else telemetry.BUILDERS[name](self.snapshot())

    def _imu_now(self):
        """One HIGHRES_IMU sample of the present state (level yaw rate, the tilt the vehicle flies)."""
        nav, yaw = self.nav, yaw_enu_to_ned(self.nav.yaw)
        att = tilt(nav.accel, yaw) if nav.attitude is None else tuple(nav.attitude[:2])
        return self.imu.sample(self.t, (*att, yaw), (0.0, 0.0, -self._yaw_rate), nav.accel,
                               self.home.alt_m + float(nav.pos[2]), self.imu.noise_now)

    def set_message_interval(self, msg_id: int, interval_us: float) -> bool:
        if msg_id == M.MAVLINK_MSG_ID_HIGHRES_IMU:
            self.imu.set_interval(interval_us)
            log.info("HIGHRES_IMU: %g Hz asked, %g Hz of sim time sent (at most %g a wall second)",
                     self.imu.requested_hz, self.imu.rate_hz, imu_model.MAX_WALL_HZ)
            return True
        name = telemetry.MSG_IDS.get(msg_id)
        if name is None or name == "AUTOPILOT_VERSION":
            return False
        self.scheduler.set_interval(name, interval_us)
        return True

    def inject_failure(self, unit: int, ftype: int, instance: int) -> int:
        result, text = self.failures.inject(unit, ftype, instance)
        self.statustext(text, M.MAV_SEVERITY_WARNING if result == M.MAV_RESULT_ACCEPTED else M.MAV_SEVERITY_INFO)
        return result

    def calibrate(self, params: tuple[float, ...]) -> int:
        return self.calibrations.command(params, self.nav.armed, self.t)

    def _shell_status(self) -> ShellStatus:
        return ShellStatus(self.nav.armed, self.nav.mode, self.failsafe_active)

    def _shell_command(self, command: int, params: tuple[float, float, float, float]) -> commands.Answer:
        """A shell's ``commander`` subcommand: the MAVLink command, answered as a COMMAND_LONG (without an ACK)."""
        self.stats["commands"] += 1
        ans = commands.answer(commands.Command(command, params, math.nan, math.nan, math.nan, M.MAV_FRAME_GLOBAL), self)
        log.info("shell: command %d %s -> result %d", command, params, ans.result)
        if ans.reason:
            self.statustext(f"command {command} refused: {ans.reason}", M.MAV_SEVERITY_WARNING)
        return ans

    def takeoff_note(self, text: str) -> None:
        self.statustext(text, M.MAV_SEVERITY_CRITICAL)  # PX4 logs it as critical

    def offboard_alive(self) -> bool:
        return self.offboard.alive(time.monotonic())

    def statustext(self, text: str, severity: int = M.MAV_SEVERITY_INFO) -> None:
        log.info("STATUSTEXT: %s", text)
        self.ulog.text(self.t, severity, text)
        self._text_id = (self._text_id + 1) % 65536
        for m in telemetry.statustext(text, severity, self._text_id):
            self.link.send(m)

    # -- incoming --------------------------------------------------------------------------------
    def _for_us(self, msg) -> bool:
        ts = getattr(msg, "target_system", 0)
        tc = getattr(msg, "target_component", 0)
        return ts in (0, self.cfg.sysid) and tc in (0, self.cfg.compid)

    def dispatch(self, ep: Endpoint, msg, now_wall: float) -> None:
        """Answer one incoming message; a message that makes no sense is ignored and logged."""
        kind = msg.get_type()
        try:
            if kind in ("COMMAND_LONG", "COMMAND_INT"):
                if not self._for_us(msg):
                    return
                self.stats["commands"] += 1
                cmd = commands.Command.from_msg(msg)
                ans = commands.answer(cmd, self)  # total: every command gets its ACK
                log.info("command %d %s -> result %d", cmd.command, cmd.params, ans.result)
                self.link.send(M.MAVLink_command_ack_message(cmd.command, ans.result, 0, ans.param,
                                                             msg.get_srcSystem(), msg.get_srcComponent()), ep)
                if ans.reason:
                    self.statustext(f"command {cmd.command} refused: {ans.reason}", M.MAV_SEVERITY_WARNING)
                for m in ans.extra:
                    self.link.send(m, ep)
                if cmd.command == M.MAV_CMD_DO_SET_MISSION_CURRENT and ans.result == M.MAV_RESULT_ACCEPTED:
                    self.link.send(telemetry.mission_current(self.snapshot()))
            elif kind in MISSION_MSGS:
                if not self._for_us(msg):
                    return
                for m in self.protocol.handle(msg, now_wall, self.nav.seq):
                    self.link.send(m, ep)
                if self.protocol.uploading:
                    self._proto_ep = ep
                self._react_to_mission_change()
            elif kind == "MISSION_SET_CURRENT":
                if self._for_us(msg) and self.nav.set_current(int(msg.seq)):
                    self.link.send(telemetry.mission_current(self.snapshot()))
            elif kind == "SET_MODE":
                if msg.target_system == self.cfg.sysid:
                    result = commands.set_mode_message(msg, self.nav)
                    self.link.send(M.MAVLink_command_ack_message(M.MAVLINK_MSG_ID_SET_MODE, result, 0, 0,
                                                                 msg.get_srcSystem(), msg.get_srcComponent()), ep)
            elif kind in SETPOINT_MSGS:
                if self._for_us(msg):
                    self._on_setpoint(msg, now_wall)
            elif kind == "SET_ATTITUDE_TARGET":
                if self._for_us(msg):
                    self._on_attitude(msg, now_wall)
            elif kind in PARAM_MSGS:
                if self._for_us(msg):
                    for m in self.params.handle(msg):
                        self.link.send(m, ep)
                    self._log_param_changes()
            elif kind == "FOLLOW_TARGET":
                self.follow.receive(msg, self.t, now_wall)
            elif kind == "MANUAL_CONTROL":
                if msg.target in (0, self.cfg.sysid):
                    self.manual.receive(sticks_from_msg(msg), now_wall)
            elif kind == "FILE_TRANSFER_PROTOCOL":
                if self._for_us(msg) and msg.target_network == 0:
                    src = (msg.get_srcSystem(), msg.get_srcComponent())
                    for payload in self.ftp.handle(msg.payload, src):
                        self._bulk.append((M.MAVLink_file_transfer_protocol_message(0, *src, list(payload)), ep))
            elif kind == "SERIAL_CONTROL":
                for m in self.shell.handle(msg, ep.name):
                    self._bulk.append((m, ep))
                self._log_param_changes()
            elif kind in LOG_MSGS:
                if self._for_us(msg):
                    self._log_ep = ep
                    for m in self.logs.handle(msg):
                        self.link.send(m, ep)
            elif kind == "PING":
                if msg.target_system == 0:
                    self.link.send(M.MAVLink_ping_message(msg.time_usec, msg.seq, msg.get_srcSystem(),
                                                          msg.get_srcComponent()), ep)
            elif kind == "TIMESYNC":
                if msg.tc1 == 0:
                    self.link.send(M.MAVLink_timesync_message(int(self.t * 1e9), msg.ts1), ep)
            else:
                self.stats["ignored"] += 1
        except Exception as exc:  # noqa: BLE001 - bad input is ignored and logged, never fatal
            log.warning("%s from %d/%d ignored: %s: %s", kind, msg.get_srcSystem(), msg.get_srcComponent(),
                        type(exc).__name__, exc)

    def _log_param_changes(self) -> None:
        """A parameter set in flight goes into the ULog where it happened (PX4's logger does the same)."""
        for p in self.params.params:
            if self._logged_params[p.name] != p.value:
                self._logged_params[p.name] = p.value
                self.ulog.param_changed(p.name, p.value, p.ptype == INT32)

    def flush_bulk(self, n: int = BULK_PER_TURN) -> None:
        """Send up to ``n`` queued file-transfer packets (FTP replies first, then the log download's)."""
        while self._bulk and n > 0:
            self.link.send(*self._bulk.popleft())
            n -= 1
        if n > 0 and self._log_ep is not None:
            for m in self.logs.pending(n):
                self.link.send(m, self._log_ep)

    def _on_setpoint(self, msg, now_wall: float) -> None:
        try:
            sp = offboard.setpoint_from_msg(msg, self.home, self.nav.yaw)
        except offboard.SetpointError as exc:
            log.info("%s ignored: %s", msg.get_type(), exc)
            return
        if sp.pos is not None and not self.fence.contains(sp.pos):
            if self._refused_sp is None or not np.array_equal(self._refused_sp, sp.pos):  # say it once
                self._refused_sp = sp.pos
                self.statustext(f"offboard setpoint {np.round(sp.pos, 1).tolist()} m outside the geofence: ignored",
                                M.MAV_SEVERITY_WARNING)
            return
        self.offboard.receive(sp, now_wall)
        self.nav.offboard_setpoint = sp

    def _on_attitude(self, msg, now_wall: float) -> None:
        try:
            sp = offboard.attitude_setpoint_from_msg(msg)
        except offboard.SetpointError as exc:
            log.info("SET_ATTITUDE_TARGET ignored: %s", exc)
            return
        self.offboard.receive(sp, now_wall)
        self.nav.offboard_setpoint = sp

    def _check_offboard(self, now_wall: float) -> None:
        """The setpoint stream must go on while in OFFBOARD: lost for COM_OF_LOSS_T -> HOLD."""
        if self.offboard.setpoint is None or self.offboard.alive(now_wall):
            return
        self.nav.offboard_setpoint = None
        self.offboard.setpoint = None
        if self.nav.mode is Mode.OFFBOARD:
            self.nav.hold()
            self.statustext(f"Failsafe: offboard setpoints lost for {self.offboard.loss_timeout_s:g} s, holding",
                            M.MAV_SEVERITY_CRITICAL)

    def _check_streams(self, now_wall: float) -> None:
        """A follow target or the virtual sticks gone quiet: hold where it is (PX4: target / RC lost)."""
        if self.follow.expire(now_wall) and self.nav.mode is Mode.FOLLOW:
            self.statustext("Follow target lost, holding position", M.MAV_SEVERITY_WARNING)
        if self.manual.expire(now_wall) and self.nav.mode in MANUAL_MODES:
            self.statustext("Manual control lost, holding position", M.MAV_SEVERITY_CRITICAL)

    def _react_to_mission_change(self) -> None:
        if self.protocol.changed:
            self.protocol.changed = False
            self.nav.replace_mission(self.protocol.items)
        if self.protocol.changed_types:
            changed, self.protocol.changed_types = self.protocol.changed_types, set()
            if M.MAV_MISSION_TYPE_FENCE in changed:
                zones = zones_from_items(self.protocol.lists[M.MAV_MISSION_TYPE_FENCE], self._to_enu_xy)
                self.fence = self.fence.with_zones(zones)
                self.statustext(f"Geofence: {len(zones)} zone(s) uploaded")
            if M.MAV_MISSION_TYPE_RALLY in changed:
                rally = self.protocol.lists[M.MAV_MISSION_TYPE_RALLY]
                self.nav.rally_points = [self.nav.item_target(i) for i in rally]
                self.statustext(f"Rally: {len(rally)} point(s) uploaded")

    # -- simulation ------------------------------------------------------------------------------
    def step(self, dt: float, link_age: float | None) -> list:
        """One sim step (``SimVehicle.step``), its events told over MAVLink."""
        events = super().step(dt, link_age)
        nav = self.nav
        for m in self.imu.step(self.t, dt, nav.accel, nav.yaw, self._yaw_rate, self.home.alt_m + float(nav.pos[2]),
                               float(nav.vel[2]), None if nav.attitude is None else nav.attitude[:2]):
            self.link.send(m)
        for text, severity in self.calibrations.due(self.t):
            self.statustext(text, severity)
        due = self.ulog.due(self.t)
        if due:
            self.ulog.record(self.snapshot(), self._imu_now() if "sensor_combined" in due else None, due)
        for ev in events:
            if ev.kind == "reached":
                self.link.send(M.MAVLink_mission_item_reached_message(int(ev.data)))
                self.link.send(telemetry.mission_current(self.snapshot()))
            elif ev.kind == "text":
                self.statustext(*ev.data)
            elif ev.kind == "mode":
                log.info("mode %s", ev.data.value)
        self.stats["steps"] += 1
        return events

    def emit(self) -> None:
        due = self.scheduler.due(self.t)
        if due:
            snap = self.snapshot()
            for name in due:
                self.link.send(telemetry.BUILDERS[name](snap))
        if self._zenoh is not None and self._zenoh.ready:
            # on the step grid (every _pose_every steps, and where lockstep holds), so the same flight
            # publishes its poses at the same sim times however the steps were paced in wall time
            with_pose = self.t > self._last_pose_t and (self.stats["steps"] % self._pose_every == 0
                                                        or self.t >= self._hold_until - 1e-9)
            if with_pose:
                self._last_pose_t = self.t
            self._zenoh.publish(self.t, self.truth(), (self.nav.pos, self.nav.yaw), self.odo.var, with_pose)

    def stop(self) -> None:
        self._stop.set()

    def _refused(self, reason: str) -> None:
        """The zenoh session cannot be had (refused credentials, a bad credentials or config file): stop."""
        self.zenoh_refused = reason
        log.error("zenoh: %s: stopping", reason)
        self._stop.set()

    def run(self, max_sim_time: float | None = None) -> None:
        """The loop: fixed sim steps paced by a FreeRunningClock at ``speedup``; with ``cfg.lockstep``
        never past the sim time the mission process allows (``vehicle_sim.lockstep``)."""
        import select

        from radseek.simclock import FreeRunningClock

        cfg = self.cfg
        gate = None
        if cfg.lockstep:
            from vehicle_sim.lockstep import LockstepGate

            gate = self.lockstep = LockstepGate(cfg.lockstep_timeout_s)
        if cfg.zenoh:
            self._zenoh = _ZenohOut(cfg, gate, self._refused)
        # while lockstep holds sim time, telemetry goes on in wall time (as at 1x) so that MAVSDK and a
        # GCS keep their link (heartbeats) through a long pause; SET_MESSAGE_INTERVAL applies to both
        hold_sched = telemetry.Scheduler(1.0, cfg.max_wall_hz)
        hold_sched.rates = self.scheduler.rates
        held_since: float | None = None
        last_emit = -math.inf
        clock = FreeRunningClock(cfg.speedup, t0=self.t)
        dt = cfg.dt
        log.info("vehicle up: api %s -> %s, gcs %s -> %s, speedup %g", self.link.endpoints[0].local_address,
                 self.link.endpoints[0].target, self.link.endpoints[1].local_address, self.link.endpoints[1].target,
                 cfg.speedup)
        try:
            while not self._stop.is_set():
                now_wall = time.monotonic()
                # lockstep: read the limit *before* draining MAVLink: the mission sends its commands first
                # and acks after, so every command sent before an ack is applied before the steps it allows
                limit = gate.limit(now_wall) if gate is not None else None
                if gate is not None:
                    gate.drain_wake()
                for ep, msg in self.link.recv(now_wall):
                    self.dispatch(ep, msg, now_wall)
                for m in self.protocol.poll(now_wall):
                    self.link.send(m, self._proto_ep)
                self.flush_bulk()
                self._check_offboard(now_wall)
                self._check_streams(now_wall)
                last = self.link.last_rx_wall
                link_age = None if last is None else now_wall - last
                target = clock.now()
                self._hold_until = math.inf if limit is None else limit
                if limit is not None:
                    target = min(target, limit)
                n = 0
                end = math.inf if max_sim_time is None else max_sim_time - 1e-9  # --duration: never step past it
                while self.t + dt <= target + 1e-9 and n < 50 and self.t < end:
                    self.step(dt, link_age)
                    self.emit()  # every step: poses and clock at the same sim times however steps are paced
                    n += 1
                if n:
                    last_emit = now_wall
                elif now_wall - last_emit >= 0.1:  # no step: keep followers fed, 10 Hz of wall time
                    self.emit()
                    last_emit = now_wall
                held = limit is not None and self.t + dt > limit + 1e-9
                if held or target - self.t > 1.0:  # held, or fell behind: no debt to run off in a burst
                    clock = FreeRunningClock(cfg.speedup, t0=self.t)
                held_since = self._account_hold(held, held_since, now_wall, hold_sched, gate)
                if self.t >= end:
                    break
                if held:  # wake at once on a mission/lockstep message or a MAVLink datagram
                    socks = [e.sock for e in self.link.endpoints] + [gate.wake_socket]
                    select.select(socks, [], [], 0.05)
                    continue
                wait = (self.t + dt - clock.now()) / cfg.speedup
                if wait > 0:
                    self.link.wait(min(wait, 0.02))
        finally:
            if gate is not None:
                gate.close()
            if self._zenoh is not None:
                self._zenoh.close()
            self.link.close()

    def _account_hold(self, held: bool, held_since: float | None, now_wall: float, hold_sched, gate) -> float | None:
        """Lockstep bookkeeping: wall-time telemetry during a hold, pauses counted and logged."""
        if held:
            if held_since is None:
                return now_wall
            if now_wall - held_since > 0.25:
                due = hold_sched.due(now_wall)
                if due:
                    snap = self.snapshot()
                    for name in due:
                        self.link.send(telemetry.BUILDERS[name](snap))
            return held_since
        if held_since is not None:
            w = now_wall - held_since
            self.stats["lockstep_held_wall_s"] += w
            if w > 1.0:
                self.stats["lockstep_pauses"] += 1
                log.info("lockstep: held %.1f s wall at t=%.2f s while the mission computed (no sim time passed)",
                         w, self.t)
        return None
