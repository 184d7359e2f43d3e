"""One simulated world, stepped: the vehicle (``SimVehicle``) and its detector board on one sim clock.

This is ``radseek run``'s stack minus its sockets, for the in-process driver (``launch.offline``), the
campaigns and the benchmarks. It keeps the stack's timing rules, so the same seed flies the same flight:

* the vehicle steps in fixed ``dt`` sim steps (``radseek vehicle --dt``, 0.05 s) up to the time lockstep
  allows (``step_to``), publishing its true pose every step and its estimated pose on the 0.1 s grid and
  where it holds (``Vehicle.emit``);
* the board measures frame ``k`` (``[k T, (k+1) T)``) once the vehicle is at its end, at the true pose
  interpolated at its mid-time (``detector_fw_sim.readout``), and the frame goes through the wire
  encoding and the driver as the detector process publishes it (``DetectorProcess.produce``);
* payloads are the contracts' own (``topics.TruthPose``, ``topics.Pose``, ``topics.Histogram``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from detector_fw_sim.board import Board
from detector_fw_sim.readout import CountSource, read_out, true_pose_for
from radseek import topics
from radseek.board_wire import FrameConsumer, encode_frame, frame_to_histogram
from radseek.pose_history import PoseHistory
from vehicle_sim.sim_vehicle import SimEvent, SimVehicle

if TYPE_CHECKING:
    from vehicle_sim.vehicle import VehicleConfig

#: sim s without a true pose before a frame is stale (``radseek detector --stale-after`` default)
STALE_AFTER_S = 0.5


class World:
    """The vehicle and its detector stepped together; ``step_to(until)`` then ``frame()`` per 100 ms frame."""

    def __init__(self, vehicle: VehicleConfig, emulator: CountSource, *, stale_after_s: float = STALE_AFTER_S):
        self.vehicle = SimVehicle(vehicle)
        self.dt = vehicle.dt
        self.emulator = emulator
        self.board = Board()
        self.stale_after_s = stale_after_s
        self.truth_poses: PoseHistory[topics.TruthPose] = PoseHistory(keep_s=30.0)  # as the detector keeps them
        self._driver = FrameConsumer(first_is_gap=True)
        self._pose_every = max(1, round(0.1 / vehicle.dt))
        self._last_pose_t = -1.0
        self.k = 0  # the next frame to measure
        self.last_true_pose: np.ndarray | None = None  # the true pose the last frame was measured at
        self.poses: list[topics.Pose] = []  # estimated poses as the vehicle publishes them (unread ones)
        self.events: list[SimEvent] = []  # the vehicle's events not yet read
        self._emit(hold_until=0.0)  # at t = 0 the vehicle holds and publishes its pose

    @property
    def t(self) -> float:
        return self.vehicle.t

    def _emit(self, hold_until: float) -> None:
        """What ``Vehicle.emit`` publishes after a step: the true pose always, the estimate on the grid."""
        v = self.vehicle
        p, yaw = v.truth()
        self.truth_poses.add(topics.TruthPose(t=v.t, x=float(p[0]), y=float(p[1]), z=float(max(p[2], 0.0)),
                                              yaw=float(yaw)))
        if v.t > self._last_pose_t and (v.steps % self._pose_every == 0 or v.t >= hold_until - 1e-9):
            self._last_pose_t = v.t
            (e, eyaw), var = v.estimate(), v.odo.var
            self.poses.append(topics.Pose(t=v.t, x=float(e[0]), y=float(e[1]), z=float(e[2]), yaw=float(eyaw),
                                          var_x=float(var[0]), var_y=float(var[1]), var_z=float(var[2]),
                                          var_yaw=float(var[3])))

    def step_to(self, until: float, link_age: float | None = 0.0) -> None:
        """Step the vehicle to sim time ``until`` (lockstep's limit), as ``Vehicle.run`` does; ``link_age``:
        wall s since the ground link last spoke (0: the mission's link is alive, as in the stack)."""
        while self.vehicle.t + self.dt <= until + 1e-9:
            self.events += self.vehicle.step(self.dt, link_age)
            self._emit(until)

    def frame(self) -> topics.Histogram | None:
        """The next board frame, its interval ended (``step_to`` its end first); None if the driver rejects it."""
        k = self.k
        t0, t1 = self.board.interval(k)
        if self.vehicle.t < t1 - 1e-6:
            raise RuntimeError(f"frame {k} ends at t={t1:g} s but the vehicle is at t={self.vehicle.t:g} s")
        pose = true_pose_for(self.truth_poses.latest(), self.truth_poses.at, t0, t1, self.stale_after_s)
        got = read_out(self.board, self.emulator, k, pose)
        self.k += 1
        self.last_true_pose = pose
        accepted = self._driver.accept(encode_frame(got.frame))
        if accepted is None:
            return None
        frame, gap = accepted
        return frame_to_histogram(frame, t=t1, flags=gap, live_time=got.live_time)

    def take_poses(self) -> list[topics.Pose]:
        out, self.poses = self.poses, []
        return out

    def take_events(self) -> list[SimEvent]:
        out, self.events = self.events, []
        return out
