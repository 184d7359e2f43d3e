"""Fly a team of N vehicles in-process against the emulator: the joint brain (``mission.team``) with N
``launch.offline`` flights stepped together frame by frame on one sim clock.

Each vehicle has its own emulator stream, its own odometry drift (its own seed) and its own records, like
one mock autopilot and one detector per vehicle in ``radseek run --vehicles N``; the brain sees the team's
frames (``mission.team.team_frames``). A vehicle may be failed at a sim time (``fail``: it stops where it
is and records nothing more, its reservation stays): the others finish the search. Used by
``benchmarks/team_search.py`` and the fast team tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from detector_fw_sim.emulator import DetectorEmulator
from detector_fw_sim.scene import Scene
from launch.offline import FRAME_S, EstimateAndError
from mission.search import SearchConfig, reproducible
from mission.team import TeamBrain, TeamConfig, TeamDecision, home_positions, team_frames
from planner.allocation import Reservation, pairwise_min_distance
from planner.belief import drift_density_from_poses
from radseek import topics
from radseek.dataset import Dataset, Frames
from radseek.frame_record import FrameRecord
from vehicle_sim.odometry import Odometry, OdometryParams


class _Flight:
    """Frame-by-frame flight of the earlier in-process model: constant speed with a yaw-rate limit, the
    emulator's counts without the board. Only the team driver still flies it: the team's missions have not
    moved onto the one executive and world (``mission.executive``, ``vehicle_sim.world``) yet, so team
    figures come from this simpler world (issue 31)."""

    def __init__(self, scene: Scene, start: np.ndarray, seed: int, speed: float, yaw_rate_max: float,
                 odometry: OdometryParams | None):
        self.channel_edges_keV = scene.scenario().channel_edges_keV
        self.emulator = DetectorEmulator(scene, seed=seed)
        self.odo = Odometry(odometry, seed=seed + 1)
        self.est = np.asarray(start, dtype=float).copy()  # (4,) estimated pose: what the vehicle flies on
        self.t = 0.0
        self.speed = speed
        self.yaw_rate_max = yaw_rate_max
        self.records: list[FrameRecord] = []
        self.true_path: list[np.ndarray] = []
        self.seq = 0

    def true_pose(self) -> np.ndarray:
        pos, yaw = self.odo.truth_from_estimate(self.est[:3], self.est[3])
        return np.r_[pos, yaw]

    def frame(self, dwell: int) -> topics.Histogram:
        mid = self.true_pose()
        counts = self.emulator.draw(mid, self.t + FRAME_S / 2, FRAME_S)
        self.t += FRAME_S
        var = self.odo.var
        self.seq += 1
        hist = topics.Histogram(seq=self.seq, board_time=self.t, t=self.t, duration=FRAME_S,
                                counts=[int(c) for c in counts])
        pose = topics.Pose(t=self.t, x=float(self.est[0]), y=float(self.est[1]), z=float(self.est[2]),
                           yaw=float(self.est[3]), var_x=float(var[0]), var_y=float(var[1]), var_z=float(var[2]))
        self.records.append(FrameRecord.from_histogram(hist, pose, dwell, self.channel_edges_keV))
        self.true_path.append(mid)
        return hist

    def fly_to(self, target: np.ndarray) -> np.ndarray:
        """Fly (estimated frame) to target (x, y, z, yaw), recording transit frames; returns visited xyz."""
        visited = []
        while self.step(target) is not None:
            visited.append(self.est[:3].copy())
        return np.array(visited).reshape(-1, 3)

    def step(self, target: np.ndarray) -> float | None:
        """One transit frame toward target (x, y, z, yaw) at most speed and yaw rate; the distance it moved,
        None once there (no frame is recorded then)."""
        d = target[:3] - self.est[:3]
        dist = float(np.linalg.norm(d))
        dyaw = math.remainder(target[3] - self.est[3], 2 * math.pi)
        if dist < 1e-6 and abs(dyaw) < 1e-6:
            return None
        step = min(dist, self.speed * FRAME_S)
        turn = float(np.clip(dyaw, -self.yaw_rate_max * FRAME_S, self.yaw_rate_max * FRAME_S))
        # the mid-frame pose is what the frame integrates: move half, record, move the other half
        self.est[:3] += d / max(dist, 1e-12) * step / 2
        self.est[3] += turn / 2
        self.odo.advance(step / 2)
        self.frame(dwell=-1)
        self.est[:3] += d / max(dist, 1e-12) * step / 2
        self.est[3] = math.remainder(self.est[3] + turn / 2, 2 * math.pi)
        self.odo.advance(step / 2)
        return step

    def frames(self) -> Frames:
        return Frames.from_records(self.records)


#: a team flight stops after this much sim time whatever the brain says (a stuck allocation is a bug)
MAX_SIM_S = 3600.0


class _TeamFlight(_Flight):
    """One vehicle: ``_Flight`` stepped one frame at a time (``step``) instead of a leg at a time."""

    def __init__(self, index: int, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.index = index
        self.waypoints: list[np.ndarray] = []
        self.mode = "fly"  # fly | dwell | hold | failed | done
        self.hold_until = 0.0
        self.dwell_index = -1
        self.n_dwells = 0
        self.visited: list[np.ndarray] = []
        self.dwell_positions: list[np.ndarray] = []
        self.distance_m = 0.0

    def step_to(self, target: np.ndarray) -> bool:
        """One frame toward ``target`` (x, y, z, yaw), as ``_Flight.fly_to`` flies it (``_Flight.step``); True
        once there (no frame is recorded then)."""
        step = self.step(target)
        if step is None:
            return True
        self.distance_m += step
        self.visited.append(self.est[:3].copy())
        return False

    def hover(self) -> None:
        self.frame(dwell=-1)

    def pose_var(self) -> tuple[float, float]:
        """The x-y variance its pose reports now and its growth per metre flown, from its own frames (as the
        mission process knows them: the reported variance, not the simulator's drift parameters)."""
        f = self.frames() if self.records else None
        density = float(drift_density_from_poses(f.positions, f.pose_variances, f.dwell)[0]) if f is not None else 0.0
        return float(self.odo.var[0]), density

    def reservation(self) -> Reservation:
        """Where it is, then the waypoints it still has to fly (its dwell point last), with its pose variance
        at the end of them."""
        path = self.est[None, :3].copy() if self.mode != "fly" else \
            np.vstack([self.est[:3]] + [w[:3] for w in self.waypoints])
        var, density = self.pose_var()
        length = float(np.linalg.norm(np.diff(path[:, :2], axis=0), axis=1).sum()) if len(path) > 1 else 0.0
        return Reservation(path, var + density * length)


@dataclass
class TeamResult(EstimateAndError):
    dataset: Dataset  # the team's frames (vehicle by vehicle, team dwell indices) with the truth
    brain: TeamBrain
    decisions: list[TeamDecision]
    mission_time_s: float
    per_vehicle: list[dict]  # {dwell_points, distance_m, dwell_positions (K, 3), true_path (N, 4), failed_at}
    min_separation_m: float  # the smallest true x-y distance between two vehicles over the flight
    min_separation_est_m: float  # the same on the vehicles' estimated poses (what the allocation holds)
    log: list[str] = field(default_factory=list)


def fly_team_offline(scene: Scene, n_vehicles: int = 2, config: SearchConfig | None = None, seed: int = 0,
                     team: TeamConfig | None = None, speed: float = 1.0, yaw_rate_max: float = math.radians(45),
                     odometry: OdometryParams | None = None, fail: dict[int, float] | None = None,
                     verbose: bool = False) -> TeamResult:
    """Fly the team's search; ``fail`` {vehicle: sim time} fails vehicles mid-flight. Vehicle v's counts and
    drift are seeded ``seed + 1000 v`` (vehicle 0 draws as ``fly_offline`` with ``seed``)."""
    from planner.dwell_tree import seed_ompl

    config = reproducible(config or SearchConfig())
    team = team or TeamConfig(n_vehicles=n_vehicles)
    if team.n_vehicles != n_vehicles:
        raise ValueError("team.n_vehicles and n_vehicles differ")
    fail = dict(fail or {})
    seed_ompl(seed + 1)
    scenario = scene.scenario()
    brain = TeamBrain(scenario, config, team, seed=seed)
    homes = home_positions(scenario, team)
    flights = [_TeamFlight(v, scene, np.r_[homes[v], config.altitude_m, 0.0], seed + 1000 * v, speed, yaw_rate_max,
                           odometry) for v in range(n_vehicles)]
    decisions: list[TeamDecision] = []
    log: list[str] = []
    min_sep = min_sep_est = math.inf

    def reserved(exclude: int) -> dict[int, Reservation]:
        """The others' reservations; tells the brain ``exclude``'s own pose variance (it is about to decide)."""
        brain.set_pose_variance(exclude, *flights[exclude].pose_var())
        return {f.index: f.reservation() for f in flights if f.index != exclude}

    def apply(f: _TeamFlight, d: TeamDecision) -> None:
        decisions.append(d)
        if d.plan is not None:
            f.mode = "fly"
            f.waypoints = [p for p in d.plan.path[1:]] + [d.plan.dwell_points[0]]
        elif d.retire:
            f.mode = "retired"
        elif d.hold_s > 0:
            f.mode, f.hold_until = "hold", f.t + d.hold_s
        else:
            f.mode = "done"

    for f in flights:  # in index order: each start sees the reservations the earlier ones made
        apply(f, brain.start(f.est, f.index, reserved(f.index)))
    t = 0.0
    while brain.final is None and t < MAX_SIM_S and any(f.mode in ("fly", "dwell", "hold") for f in flights):
        t += FRAME_S
        for f in flights:
            if f.index in fail and t >= fail[f.index] and f.mode != "failed":
                f.mode = "failed"
                log.append(f"t={t:7.1f}s vehicle {f.index} failed at ({f.est[0]:.2f}, {f.est[1]:.2f})")
            if brain.final is not None:
                break
            if f.mode == "fly":
                while f.waypoints and f.step_to(f.waypoints[0]):
                    f.waypoints.pop(0)
                if not f.waypoints:  # arrived: the dwell starts with the next frame
                    f.mode = "dwell"
                    f.dwell_index = f.n_dwells
                    brain.begin_dwell(f.index)
            elif f.mode == "dwell":
                status = brain.on_frame(f.frame(dwell=f.dwell_index), f.index)
                if status.done:
                    f.n_dwells += 1
                    f.dwell_positions.append(f.est[:3].copy())
                    flown = np.array(f.visited).reshape(-1, 3)
                    f.visited = []
                    frames = team_frames([g.frames() for g in flights])
                    d = brain.end_dwell(f.est[:3].copy(), status, frames, f.est.copy(), flown, f.index,
                                        reserved(f.index))
                    msg = (f"t={f.t:7.1f}s vehicle {f.index} dwell {f.dwell_index} at ({f.est[0]:.2f}, "
                           f"{f.est[1]:.2f}) {status.mean_rate:8.1f} cps for {status.live_time:4.1f}s -> "
                           f"{d.phase}: {d.reason}")
                    log.append(msg)
                    if verbose:
                        print(msg, flush=True)
                    apply(f, d)
            elif f.mode == "hold":
                f.hover()
                if f.t >= f.hold_until - 1e-9:
                    apply(f, brain.replan(f.index, f.est.copy(), reserved(f.index)))
            elif f.mode in ("failed", "done", "retired"):
                f.t = t  # the clock goes on; a failed vehicle records nothing more
        min_sep = min(min_sep, pairwise_min_distance(np.array([f.true_pose()[:3] for f in flights])))
        min_sep_est = min(min_sep_est, pairwise_min_distance(np.array([f.est[:3] for f in flights])))
    mission_time = max(f.t for f in flights if f.mode != "failed") if any(f.mode != "failed" for f in flights) else t
    frames = team_frames([f.frames() for f in flights])
    per_vehicle = [{
        "dwell_points": f.n_dwells, "distance_m": f.distance_m,
        "dwell_positions": np.array(f.dwell_positions).reshape(-1, 3), "true_path": np.array(f.true_path),
        "failed_at": fail.get(f.index) if f.mode == "failed" else None,
    } for f in flights]
    return TeamResult(dataset=Dataset(frames=frames, scenario=scenario, truth=scene.truth()), brain=brain,
                      decisions=decisions, mission_time_s=float(mission_time), per_vehicle=per_vehicle,
                      min_separation_m=min_sep, min_separation_est_m=min_sep_est, log=log)


__all__ = ["TeamResult", "fly_team_offline"]
