"""Fly a team of N vehicles in-process: ``radseek run --vehicles N`` minus its sockets.

Each vehicle is what ``radseek run`` starts for it: its own world (the mock autopilot's vehicle and a detector
board, ``vehicle_sim.world``; counts and drift seeded ``seed + 1000 v``, launch point
``mission.team.home_positions``) and its own team executive (``mission.team_executive``: its own team brain,
fed by what the teammates say). What the zenoh team traffic carries between mission processes goes through a
shared board here (``InProcessTeam``). The vehicles take their frames in turn, as over zenoh
(``mission.team_link``): so each decides on what the others said up to a known frame, and the same seed flies
the same team flight.

A vehicle may be failed at a sim time (``fail``): its mission stops where it is (the vehicle hovers, records
nothing more, its last reservation stays) and the teammates are told once, as a silent teammate is over zenoh.
Used by ``benchmarks/team_search.py`` and the fast team tests.
"""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass, field

import numpy as np

from detector_fw_sim.emulator import DetectorEmulator
from detector_fw_sim.scene import Scene
from launch.offline import RUN_MAX_SPEED_M_S, EstimateAndError, InProcessFrames, InProcessVehicle, vehicle_config
from mission.search import SearchConfig, reproducible
from mission.team import TeamBrain, TeamConfig, TeamDecision, home_positions, team_frames
from mission.team_executive import TeamExecutive
from mission.team_link import TeamLinkBase, label_dwells
from planner.allocation import pairwise_min_distance
from radseek import topics
from radseek.dataset import Dataset, Frames
from vehicle_sim.odometry import OdometryParams
from vehicle_sim.world import World


class VehicleFailed(Exception):
    """Raised in a vehicle's frame source at its failure time: its mission stops there."""


class TeamBoard:
    """What the team's vehicles say to each other (their statuses, their frames, the joint estimate)."""

    def __init__(self, names: tuple[str, ...]):
        self.names = names
        self.statuses: dict[str, topics.TeamStatus] = {}
        self.sources: dict[str, TeamFrames] = {}
        self.failed: dict[str, float] = {}
        self.estimate: topics.Estimate | None = None
        self._changed = asyncio.Event()

    def notify(self) -> None:
        self._changed.set()

    async def wait_for(self, ready) -> None:
        """Until ``ready()`` holds (checked whenever a vehicle says something or fails)."""
        while not ready():
            self._changed.clear()
            await self._changed.wait()


class TeamFrames(InProcessFrames):
    """A team vehicle's frames; at its failure time its mission stops."""

    def __init__(self, name: str, fail_at: float | None, *args):
        super().__init__(*args)
        self.name, self.fail_at = name, fail_at
        self.est_path: list[np.ndarray] = []  # the estimated pose at each frame's mid-time

    async def tick(self, *, first_timeout_wall_s: float | None = None) -> topics.Histogram | None:
        if self.fail_at is not None and self.t >= self.fail_at - 1e-9:
            raise VehicleFailed(self.name)
        hist = await super().tick()
        p = self.poses.at(self.t - self.frame_s / 2)
        self.est_path.append(np.array([p.x, p.y, p.z]) if p is not None else np.full(3, np.nan))
        return hist


class InProcessTeam(TeamLinkBase):
    """The team link through the board: statuses are shared objects, a teammate's frames its recorded ones."""

    def __init__(self, board: TeamBoard, me: str):
        super().__init__(me, board.names)
        self.board = board
        self._told: set[str] = set()

    def _send(self, msg: topics.TeamStatus) -> None:
        self.board.statuses[self.me] = msg
        self.board.notify()

    def _statuses(self) -> dict[str, topics.TeamStatus]:
        return {n: st for n, st in self.board.statuses.items() if n != self.me}

    def _mate_frames(self, name: str) -> Frames | None:
        src = self.board.sources.get(name)
        if src is None or not src.records:
            return None
        st = self.board.statuses.get(name)
        return label_dwells(Frames.from_records(src.records), list(st.dwells) if st is not None else [])

    def _gone(self, name: str) -> bool:
        return name in self.board.failed

    def lost(self) -> list[str]:
        return sorted(self._told)

    def publish_estimate(self, msg: topics.Estimate) -> None:
        self.board.estimate = msg

    async def wait_turn(self, t_next: float, frame_s: float) -> None:
        await self.board.wait_for(lambda: self.turn_ready(t_next, frame_s))

    def newly_silent(self) -> list[tuple[str, str]]:
        out = []
        for n, t in self.board.failed.items():
            if n != self.me and n not in self._told:
                self._told.add(n)
                out.append((n, f"its mission stopped at t={t:.1f} s"))
        return out


@dataclass
class TeamResult(EstimateAndError):
    dataset: Dataset  # the team's frames (vehicle by vehicle, team dwell indices) with the truth
    brain: TeamBrain  # the brain of the vehicle whose estimate ended the search (else vehicle 0's)
    decisions: list[TeamDecision]
    mission_time_s: float
    per_vehicle: list[dict]  # {dwell_points, distance_m, dwell_positions (K, 3), true_path (N, 4), failed_at}
    min_separation_m: float  # the smallest true x-y distance between two vehicles over the flight
    min_separation_est_m: float  # the same on the vehicles' estimated poses (what the allocation holds)
    log: list[str] = field(default_factory=list)
    summaries: list[dict] = field(default_factory=list)  # each vehicle's mission summary (None: failed)


def _min_separation(paths: list[np.ndarray]) -> float:
    """Smallest x-y distance between two vehicles at the same frame, over the frames all of them flew."""
    n = min((len(p) for p in paths), default=0)
    if len(paths) < 2 or n == 0:
        return math.inf
    stacked = np.stack([p[:n, :3] for p in paths], axis=1)  # (frames, vehicles, 3)
    return float(min(pairwise_min_distance(s) for s in stacked))


def fly_team_offline(scene: Scene, n_vehicles: int = 2, config: SearchConfig | None = None, seed: int = 0,
                     team: TeamConfig | None = None, speed: float = RUN_MAX_SPEED_M_S,
                     yaw_rate_max: float | None = None, odometry: OdometryParams | None = None,
                     fail: dict[int, float] | None = None, verbose: bool = False) -> TeamResult:
    """Fly the team's mission as ``radseek run --vehicles N --seed seed`` flies it; ``fail`` {vehicle: sim time}
    stops vehicles' missions mid-flight."""
    from planner.dwell_tree import seed_ompl

    config = reproducible(config or SearchConfig())
    team = team or TeamConfig(n_vehicles=n_vehicles)
    if team.n_vehicles != n_vehicles:
        raise ValueError("team.n_vehicles and n_vehicles differ")
    fail = dict(fail or {})
    seed_ompl(seed + 1)
    scenario = scene.scenario()
    names = tuple(f"uav{v}" for v in range(n_vehicles))
    homes = home_positions(scenario, team)

    async def fly_all():
        board = TeamBoard(names)
        executives, sources = [], []
        for v, name in enumerate(names):
            s = seed + 1000 * v
            world = World(vehicle_config(s, tuple(homes[v]), speed, yaw_rate_max, odometry),
                          DetectorEmulator(scene, seed=s))
            vehicle = InProcessVehicle(world)
            src = TeamFrames(name, fail.get(v), world, vehicle, scenario.channel_edges_keV)
            board.sources[name] = src
            brain = TeamBrain(scenario, config, team, seed=s)
            executives.append(TeamExecutive(scenario, config, brain, InProcessTeam(board, name)))
            sources.append((vehicle, src))

        async def one(v: int):
            name = names[v]
            try:
                return await executives[v].fly(*sources[v], land_in_place=True)
            except VehicleFailed:
                board.failed[name] = sources[v][1].t
                board.notify()
                return None

        return board, executives, sources, await asyncio.gather(*(one(v) for v in range(n_vehicles)))

    board, executives, sources, summaries = asyncio.run(fly_all())
    decided = [v for v, n in enumerate(names) if (st := board.statuses.get(n)) is not None and st.decided]
    brain = executives[decided[0] if decided else 0].brain
    log = [f"t={e['t']:7.1f}s {names[v]} {e['event']}: " + ", ".join(f"{k}={x}" for k, x in e.items()
                                                                   if k not in ("t", "event"))
           for v, ex in enumerate(executives) for e in ex.log]
    if verbose:
        print("\n".join(sorted(log)), flush=True)
    frames = team_frames([src.frames() for _, src in sources])
    ok = [s for s in summaries if s is not None]
    per_vehicle = [{
        "dwell_points": len(ex.team.dwells),
        "distance_m": float(np.nansum(np.linalg.norm(np.diff(np.array(src.est_path).reshape(-1, 3), axis=0),
                                                     axis=1))),
        "dwell_positions": np.array([[d["x"], d["y"], d["z"]] for d in ex.team.dwells]).reshape(-1, 3),
        "true_path": np.array(src.true_path).reshape(-1, 4),
        "failed_at": fail.get(v) if names[v] in board.failed else None,
    } for v, (ex, (_, src)) in enumerate(zip(executives, sources, strict=True))]
    return TeamResult(
        dataset=Dataset(frames=frames, scenario=scenario, truth=scene.truth()), brain=brain,
        decisions=[d for ex in executives for d in ex.decisions],
        mission_time_s=max((s["mission_time_s"] for s in ok), default=0.0), per_vehicle=per_vehicle,
        min_separation_m=_min_separation([p["true_path"] for p in per_vehicle]),
        min_separation_est_m=_min_separation([np.array(src.est_path).reshape(-1, 3) for _, src in sources]),
        log=log, summaries=list(summaries))


__all__ = ["TeamResult", "fly_team_offline"]
