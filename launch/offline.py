"""Fly the search brain in-process against the emulator: no sockets, many seeds per minute.

This is the simulator side (it sees the scene's truth); the brain it drives sees only the scenario,
the estimated poses and the histograms, exactly as over MAVLink and zenoh. The vehicle flies on its
own pose estimate like the mock autopilot (``vehicle_sim.odometry``: the truth is the estimate
minus a random-walk drift that grows with distance flown), at constant speed with a yaw-rate limit.
Used for benchmarks (error vs dwell points against the baselines) and fast end-to-end tests; the
real stack is ``radseek run``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from detector_fw_sim.emulator import DetectorEmulator
from detector_fw_sim.scene import Scene
from mission.search import Decision, Phase, SearchBrain, SearchConfig, reproducible
from radseek import topics
from radseek.dataset import Dataset, Frames
from radseek.estimate import SourceEstimate
from radseek.frame_record import FrameRecord
from vehicle_sim.odometry import Odometry, OdometryParams

FRAME_S = 0.1


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


class _Flight:
    """Frame-by-frame flight: true pose, drifting estimate, emulator counts, recorded rows."""

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


def fly_offline(scene: Scene, config: SearchConfig | None = None, seed: int = 0,
                home: tuple[float, float] | None = None, speed: float = 1.0,
                yaw_rate_max: float = math.radians(45), odometry: OdometryParams | None = None,
                verbose: bool = False) -> OfflineResult:
    """Fly a whole search; returns the recorded dataset (with truth), the brain and the mission time.

    Reproducible as `radseek run` with lockstep is: the planning trees are bounded by node count, not wall
    time (``mission.search.reproducible``), and OMPL follows the seed, so a loaded machine or the flights
    flown before in the same process do not change the flight."""
    from planner.dwell_tree import seed_ompl

    config = reproducible(config or SearchConfig())
    seed_ompl(seed + 1)  # as run_mission: OMPL refuses seed 0
    scenario = scene.scenario()
    brain = SearchBrain(scenario, config, seed=seed)
    lo = scenario.bounds_min
    home_xy = np.array(home if home is not None else (lo[0] + 0.5, lo[1] + 0.5))
    flight = _Flight(scene, np.r_[home_xy, config.altitude_m, 0.0], seed, speed, yaw_rate_max, odometry)
    log: list[str] = []
    decision = brain.start(flight.est)
    decisions = [decision]
    while decision.plan is not None:
        visited = [flight.fly_to(p) for p in decision.plan.path[1:]]
        flight.fly_to(decision.plan.dwell_points[0])
        dwell_index = len(brain.history)
        brain.begin_dwell()
        while True:
            status = brain.on_frame(flight.frame(dwell=dwell_index))
            if status.done:
                break
        decision = brain.end_dwell(flight.est[:3].copy(), status, flight.frames(), flight.est.copy(),
                                   np.concatenate(visited) if visited else None)
        decisions.append(decision)
        msg = (f"t={flight.t:7.1f}s dwell {dwell_index} at ({flight.est[0]:.2f}, {flight.est[1]:.2f}) "
               f"{status.mean_rate:8.1f} cps for {status.live_time:4.1f}s -> {decision.phase}: {decision.reason}")
        log.append(msg)
        if verbose:
            print(msg, flush=True)
    ds = Dataset(frames=flight.frames(), scenario=scenario, truth=scene.truth())
    return OfflineResult(
        dataset=ds, brain=brain, decisions=decisions, mission_time_s=flight.t,
        dwell_positions=brain.history.positions, dwell_rates=brain.history.rates,
        true_path=np.array(flight.true_path), log=log,
    )


__all__ = ["OfflineResult", "Phase", "fly_offline"]
