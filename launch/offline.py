"""Fly the mission in-process: ``radseek run``'s stack minus its sockets, many seeds per minute.

The one mission executive (``mission.executive``) flies the one simulated world (``vehicle_sim.world``:
the mock autopilot's vehicle and the detector board on one sim clock) over two in-process ports instead of
MAVSDK and zenoh. The world is stepped as lockstep steps the stack: after the mission has handled a frame
(its commands applied to the vehicle at that frame's time), the vehicle steps one frame on, then the board
measures the frame. So ``fly_offline(scene, seed=S)`` flies the flight ``radseek run SCENE --seed S``
flies (same dwell points, mission time and error), and the campaigns and benchmarks measure that flight.

This is the simulator side (it sees the scene's truth); the executive and brain it drives see only the
scenario, the estimated poses and the histograms, exactly as over MAVLink and zenoh.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from detector_fw_sim.emulator import DetectorEmulator
from detector_fw_sim.scene import Scene
from mission.client.action import ActionFailed
from mission.client.mission_upload import DwellPoint, build_items
from mission.executive import FRAME_S, MissionExecutive
from mission.search import Decision, Phase, SearchBrain, SearchConfig, reproducible
from radseek import topics
from radseek.coordinates import Home
from radseek.dataset import Dataset, Frames
from radseek.estimate import SourceEstimate
from radseek.frame_record import POSE_KEEP_S, FrameRecord, pose_for
from radseek.pose_history import PoseHistory
from vehicle_sim.mission_protocol import MissionItem
from vehicle_sim.motion import MotionLimits
from vehicle_sim.navigator import Mode
from vehicle_sim.odometry import OdometryParams
from vehicle_sim.vehicle import VehicleConfig
from vehicle_sim.world import World

#: ``radseek run`` starts its vehicle with ``--max-speed 1.0`` (m/s): the leg speed the mission expects
RUN_MAX_SPEED_M_S = 1.0


class EstimateAndError:
    """The brain's final estimate and its x-y distance to the first true source (inf without either), for a
    flight's result that has ``brain`` and ``dataset`` (``OfflineResult``, ``launch.offline_team.TeamResult``)."""

    brain: SearchBrain
    dataset: Dataset

    @property
    def estimate(self) -> SourceEstimate | None:
        return self.brain.estimate

    @property
    def error_m(self) -> float:
        est = self.estimate
        truth = self.dataset.truth
        if est is None or truth is None:
            return math.inf
        s = truth.sources[0]
        return float(math.hypot(est.x - s.x, est.y - s.y))


@dataclass
class OfflineResult(EstimateAndError):
    dataset: Dataset
    brain: SearchBrain
    decisions: list[Decision]
    mission_time_s: float
    dwell_positions: np.ndarray  # (K, 3) estimated
    dwell_rates: np.ndarray
    true_path: np.ndarray  # (N, 4) true poses at frame mid-times
    log: list[str] = field(default_factory=list)
    summary: dict = field(default_factory=dict)  # the mission's summary, as the mission process writes it


def _f32(v: float) -> float:
    """A value as a MAVLink float field carries it."""
    return float(np.float32(v))


def wire_items(points: list[DwellPoint], home: Home) -> list[MissionItem]:
    """The mission items the vehicle holds after the mission uploads ``points`` (``build_items``) over
    MAVLink: MISSION_ITEM_INT's float32 parameters and altitude, degE7 latitude and longitude."""
    return [MissionItem(i.seq, i.frame, i.command, _f32(i.param1), _f32(i.param2), _f32(i.param3), _f32(i.param4),
                        int(i.x), int(i.y), _f32(i.z), int(i.autocontinue), int(i.mission_type))
            for i in build_items(points, home)]


class InProcessVehicle:
    """The executive's ``VehicleLink`` to the world's vehicle: each command does to the navigator what the
    vehicle process does on the MAVLink message MAVSDK sends for it."""

    def __init__(self, world: World):
        self.world = world
        self.nav = world.vehicle.nav
        self.abort_reason: str | None = None
        self.airborne = False

    @property
    def battery(self) -> float:
        return self.world.vehicle.battery

    def heard(self, events) -> None:
        """The vehicle's events since the last frame, as MAVSDK's telemetry reports them to the mission."""
        for ev in events:
            if ev.kind == "text" and ev.data[0].lower().startswith("failsafe") and self.abort_reason is None:
                self.abort_reason = f"vehicle failsafe: {ev.data[0]}"
        flying = self.nav.in_air
        if self.airborne and not flying and self.abort_reason is None:
            self.abort_reason = "vehicle landed"
        self.airborne = self.airborne or flying

    async def arm(self) -> None:
        if not self.nav.arm():
            raise ActionFailed("arm", "COMMAND_DENIED")

    async def takeoff(self, altitude_m: float) -> None:
        # MAVSDK: PARAM_SET MIS_TAKEOFF_ALT (float32), then NAV_TAKEOFF without an altitude
        self.nav.p = dataclasses.replace(self.nav.p, takeoff_alt=_f32(altitude_m))
        if not self.nav.takeoff(None):
            raise ActionFailed("takeoff", "COMMAND_DENIED")

    async def fly(self, points: list[DwellPoint]) -> None:
        self.nav.replace_mission(wire_items(points, self.world.vehicle.home))
        if not self.nav.set_mode(Mode.MISSION):
            raise ActionFailed("start_mission", "ERROR")

    async def end_dwell(self) -> None:
        seq, total = min(self.nav.seq, max(len(self.nav.items) - 1, 0)), len(self.nav.items)
        if seq + 1 < total:
            self.nav.set_current(seq + 1)

    async def return_to_launch(self) -> None:
        if not self.nav.rtl():
            raise ActionFailed("return_to_launch", "COMMAND_DENIED")

    async def land(self) -> None:
        if not self.nav.land():
            raise ActionFailed("land", "COMMAND_DENIED")

    async def in_air(self) -> bool:
        return self.nav.in_air


class InProcessFrames:
    """The executive's ``FrameSource`` from the world: each ``tick`` is lockstep's ack (the world steps one
    frame on) and the frame that follows, recorded with the estimated pose at its mid-time."""

    def __init__(self, world: World, vehicle: InProcessVehicle, channel_edges_keV: np.ndarray):
        self.world, self.vehicle = world, vehicle
        self.channel_edges_keV = channel_edges_keV
        self.poses: PoseHistory[topics.Pose] = PoseHistory(keep_s=POSE_KEEP_S)  # as the mission process keeps them
        self.t = 0.0
        self.frame_s = FRAME_S
        self.dwell_index = -1
        self.records: list[FrameRecord] = []
        self.flagged: list[FrameRecord] = []
        self.true_path: list[np.ndarray] = []
        self.frames_lost = 0

    async def tick(self, *, first_timeout_wall_s: float | None = None) -> topics.Histogram | None:
        t_next = self.t + self.frame_s
        self.world.step_to(t_next)
        for p in self.world.take_poses():
            self.poses.add(p)
        self.vehicle.heard(self.world.take_events())
        hist = self.world.frame()
        if hist is None:  # the driver rejected it: lost
            self.frames_lost += 1
            self.t = t_next
            return None
        record = FrameRecord.from_histogram(hist, pose_for(hist, self.poses), self.dwell_index, self.channel_edges_keV)
        (self.records if record.usable else self.flagged).append(record)
        self.true_path.append(self.world.last_true_pose)
        if hist.t > self.t + 1e-6:
            self.t, self.frame_s = hist.t, hist.duration
        return hist

    def pose_at(self, t: float) -> topics.Pose | None:
        return self.poses.at(t)

    def pose(self) -> topics.Pose | None:
        return self.poses.latest()

    def set_dwell(self, index: int) -> None:
        self.dwell_index = index

    def frames(self) -> Frames:
        return Frames.from_records(self.records)


def vehicle_config(seed: int, home: tuple[float, float] | None = None, speed: float = RUN_MAX_SPEED_M_S,
                   yaw_rate_max: float | None = None, odometry: OdometryParams | None = None) -> VehicleConfig:
    """The vehicle ``radseek run --seed seed`` starts (``radseek vehicle --max-speed 1.0``, its defaults else)."""
    limits = MotionLimits(max_speed_xy=speed)
    if yaw_rate_max is not None:
        limits = dataclasses.replace(limits, max_yaw_rate=yaw_rate_max)
    return VehicleConfig(seed=seed, limits=limits, odometry=odometry or OdometryParams(), zenoh=False,
                         lockstep=True, start_xy=tuple(home) if home is not None else (0.0, 0.0))


def fly_offline(scene: Scene, config: SearchConfig | None = None, seed: int = 0,
                home: tuple[float, float] | None = None, speed: float = RUN_MAX_SPEED_M_S,
                yaw_rate_max: float | None = None, odometry: OdometryParams | None = None,
                verbose: bool = False) -> OfflineResult:
    """Fly a whole mission (takeoff, search, return, landing) as ``radseek run SCENE --seed seed`` flies it;
    returns the recorded dataset (with truth), the brain, its decisions and the mission time.

    ``home`` is the launch point (default the origin, as ``radseek run``), ``speed`` the vehicle's cruise speed
    (m/s), ``yaw_rate_max`` its yaw-rate limit (rad/s, default the vehicle's), ``odometry`` its drift.
    Reproducible as ``radseek run`` with lockstep is: the planning trees are bounded by node count, not wall
    time (``mission.search.reproducible``), and OMPL follows the seed."""
    from planner.dwell_tree import seed_ompl

    config = reproducible(config or SearchConfig())
    seed_ompl(seed + 1)  # as run_mission: OMPL refuses seed 0
    scenario = scene.scenario()
    world = World(vehicle_config(seed, home, speed, yaw_rate_max, odometry), DetectorEmulator(scene, seed=seed))
    vehicle = InProcessVehicle(world)
    frames = InProcessFrames(world, vehicle, scenario.channel_edges_keV)
    brain = SearchBrain(scenario, config, seed=seed)
    executive = MissionExecutive(scenario, config, brain, leg_speed_m_s=1.0)
    summary = asyncio.run(executive.fly(vehicle, frames))
    summary.update(frames_received=len(frames.records) + len(frames.flagged), frames_recorded=len(frames.records),
                   frames_flagged=len(frames.flagged), frames_lost=frames.frames_lost)
    log = [f"t={e['t']:7.1f}s {e['event']}: " + ", ".join(f"{k}={v}" for k, v in e.items() if k not in ("t", "event"))
           for e in executive.log]
    if verbose:
        print("\n".join(log), flush=True)
    ds = Dataset(frames=frames.frames(), scenario=scenario, truth=scene.truth())
    return OfflineResult(
        dataset=ds, brain=brain, decisions=executive.decisions, mission_time_s=summary["mission_time_s"],
        dwell_positions=brain.history.positions, dwell_rates=brain.history.rates,
        true_path=np.array(frames.true_path).reshape(-1, 4), log=log, summary=summary,
    )


__all__ = ["OfflineResult", "Phase", "fly_offline"]
