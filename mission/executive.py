"""The one mission executive: take off, search (the brain decides, dwell by dwell), return and land.

It flies over two ports, so the same code runs the stack and the in-process world:

* a ``VehicleLink``: the autopilot (MAVSDK over MAVLink in ``mission.client.vehicle_link``, or the
  simulated vehicle in-process in ``launch.offline``);
* a ``FrameSource``: the detector's histograms joined with the estimated pose, one frame at a time
  (zenoh with lockstep in ``mission.mission_process``, or the in-process world).

The flow is driven by frames (``tick``): take a frame, decide on data stamped with sim time (the frame,
the estimated pose at the frame's time), send the commands the decision calls for, then take the next
frame. Under lockstep a command is applied at the sim time of the frame it answers, so the same seed
flies the same flight through either pair of ports.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Protocol

import numpy as np

from mission.client.action import ActionFailed
from mission.client.mission_upload import DwellPoint
from mission.search import Decision, SearchBrain, SearchConfig
from radseek import topics
from radseek.dataset import Frames, Scenario
from radseek.estimate import SourceEstimate
from radseek.frame_record import FrameRecord
from radseek.outcome import Outcome

FRAME_S = 0.1  # s, the board's frame period until the first histogram says otherwise
ARRIVE_RADIUS_M = 0.12
ARRIVE_SETTLE_S = 0.5  # sim s the estimate must stay within the radius before a dwell starts
LANDED_Z_M = 0.03  # estimated altitude of a landed vehicle


class FlightStopped(RuntimeError):
    """The flight cannot go on (no detector frames, no pose, takeoff or landing not reached): one line, said as
    it is by ``radseek mission``; the frames recorded so far stay in the dataset."""


class VehicleLink(Protocol):
    """The autopilot as the mission commands it (local ENU m, rad)."""

    #: why the vehicle left the search (a failsafe, landed), set by the link as it hears it; None while flying
    abort_reason: str | None
    battery: float  # remaining fraction, NaN until known

    async def arm(self) -> None: ...

    async def takeoff(self, altitude_m: float) -> None: ...

    async def fly(self, points: list[DwellPoint]) -> None:
        """Replace the rest of the mission with ``points`` and fly them from the first."""

    async def end_dwell(self) -> None:
        """Stop holding at the current dwell point."""

    async def return_to_launch(self) -> None: ...

    async def land(self) -> None: ...

    async def in_air(self) -> bool: ...


class FrameSource(Protocol):
    """Histograms one at a time, each recorded with the estimated pose at its mid-time."""

    t: float  # sim time of the frame taken last (the mission's "now")
    frame_s: float  # s, the frame period
    records: list[FrameRecord]  # every usable frame recorded so far

    async def tick(self, *, first_timeout_wall_s: float | None = None) -> topics.Histogram | None:
        """The frame handled last is done (its commands are sent): take the next one, or None if it was lost."""

    def pose_at(self, t: float) -> topics.Pose | None: ...

    def set_dwell(self, index: int) -> None:
        """Frames from here belong to dwell ``index`` (-1: transit)."""

    def frames(self) -> Frames: ...


class MissionExecutive:
    """Takeoff, the search loop, return and landing, over ``vehicle`` and ``frames``."""

    def __init__(self, scenario: Scenario, config: SearchConfig, brain: SearchBrain, *, leg_speed_m_s: float = 1.0,
                 log_path: Path | None = None, put: Callable[[str, topics._Payload], None] | None = None):
        self.scenario, self.config, self.brain = scenario, config, brain
        self.leg_speed_m_s = leg_speed_m_s
        self.log_path = log_path  # mission_log.jsonl, appended as events happen (None: kept in memory only)
        self._put = put  # publishes a payload under its topic (mission/state, estimate, plan), or None
        self.log: list[dict] = []
        self.t_start: float | None = None
        self.vehicle: VehicleLink | None = None
        self.frames: FrameSource | None = None
        self.decisions: list[Decision] = []
        self.dwell_index = -1

    # ------------------------------------------------------------------------------ state
    @property
    def t(self) -> float:
        return self.frames.t if self.frames is not None else 0.0

    @property
    def abort_reason(self) -> str | None:
        return self.vehicle.abort_reason if self.vehicle is not None else None

    def search_over(self) -> Decision | None:
        """The search's end when something besides the brain and the vehicle ended it (a teammate's estimate),
        else None."""
        return None

    def on_tick(self) -> None:
        """Called before each frame is taken (a team mission says it is alive here)."""

    async def tick(self, **kw) -> topics.Histogram | None:
        self.on_tick()
        return await self.frames.tick(**kw)

    # ------------------------------------------------------------------------------ output
    def publish(self, payload: topics._Payload) -> None:
        if self._put is not None:
            self._put(payload.TOPIC, payload)

    def publish_state(self, phase: str, progress: str) -> None:
        battery = self.vehicle.battery if self.vehicle is not None else math.nan
        self.publish(topics.MissionState(t=self.t, phase=phase, dwell_index=self.dwell_index,
                                         battery=1.0 if math.isnan(battery) else battery, progress=progress))

    def event(self, kind: str, **fields) -> None:
        entry = {"t": self.t, "event": kind, **fields}
        self.log.append(entry)
        if self.log_path is not None:
            with open(self.log_path, "a") as fh:
                fh.write(json.dumps(entry) + "\n")

    def set_dwell(self, index: int) -> None:
        self.dwell_index = index
        self.frames.set_dwell(index)

    # ------------------------------------------------------------------------------ flying
    async def arrive(self, target: np.ndarray, path_length: float) -> bool:
        """Frame by frame until the estimated position (at each frame's time) has stayed within
        ARRIVE_RADIUS_M of target for ARRIVE_SETTLE_S of sim time; False after 3 x the expected flight
        time + 30 s of sim time, or when the vehicle left the search (failsafe, landed)."""
        t0 = self.t
        limit = 3.0 * path_length / self.leg_speed_m_s + 30.0
        inside_since: float | None = None
        while self.t - t0 < limit and self.abort_reason is None and self.search_over() is None:
            await self.tick()
            p = self.frames.pose_at(self.t)
            if p is not None:
                if math.dist((p.x, p.y, p.z), target[:3]) < ARRIVE_RADIUS_M:
                    inside_since = self.t if inside_since is None else inside_since
                    if self.t - inside_since >= ARRIVE_SETTLE_S:
                        return True
                else:
                    inside_since = None
        return False

    async def dwell(self):
        """Feed the frames after arrival (their interval starts there: frames integrated while still
        moving do not count) to the dwell controller until it is satisfied (None if the vehicle left
        the search meanwhile)."""
        self.brain.begin_dwell()
        while self.abort_reason is None and self.search_over() is None:
            hist = await self.tick()
            if hist is None:
                continue
            status = self.brain.on_frame(hist)
            if status.done:
                return status
        return None

    async def climb(self, altitude: float, limit_s: float = 120.0) -> None:
        """Frame by frame until the estimated altitude is within 0.2 m of ``altitude``."""
        t0 = self.t
        while True:
            await self.tick()
            p = self.frames.pose_at(self.t)
            if p is not None and p.z > altitude - 0.2:
                return
            if self.t - t0 > limit_s:
                raise FlightStopped(f"takeoff: {altitude:g} m not reached in {limit_s:g} s of sim time")

    async def landed(self, limit_s: float = 600.0) -> None:
        """Frame by frame until the estimated pose has stayed on the ground for ARRIVE_SETTLE_S."""
        t0 = self.t
        down_since: float | None = None
        while True:
            p = self.frames.pose_at(self.t)
            if p is not None and p.z <= LANDED_Z_M:
                down_since = self.t if down_since is None else down_since
                if self.t - down_since >= ARRIVE_SETTLE_S:
                    return
            else:
                down_since = None
            if self.t - t0 > limit_s:
                raise FlightStopped(f"not landed {limit_s:g} s of sim time after the return to launch")
            await self.tick()

    def current(self) -> np.ndarray:
        """The estimated pose (x, y, z, yaw) now (the dwell altitude over the origin before any pose)."""
        p = self.frames.pose_at(self.t)
        if p is None:
            return np.array([0.0, 0.0, self.config.altitude_m, 0.0])
        return np.array([p.x, p.y, p.z, p.yaw])

    async def upload(self, plan) -> np.ndarray:
        """Fly ``plan``: its path as pass-through waypoints, then its dwell point holding for the longest dwell
        allowed, from the new first item; returns the dwell point."""
        points = [DwellPoint(*p[:3], yaw=p[3], max_dwell_s=0.0) for p in plan.path[1:-1]]
        d = plan.dwell_points[0]
        points.append(DwellPoint(*d[:3], yaw=d[3], max_dwell_s=self.config.dwell.t_timeout + 30.0))
        await self.vehicle.fly(points)
        return d

    def dwelt(self, d: np.ndarray, index: int, status) -> np.ndarray:
        """Where dwell ``index`` (at dwell point ``d``) was measured: the estimated pose now (else ``d``), logged
        with the dwell's ``status``."""
        p = self.frames.pose_at(self.t)
        position = np.array([p.x, p.y, p.z]) if p is not None else d[:3]
        self.event("dwell", index=index, position=position.tolist(),
                   **{k: v for k, v in asdict(status).items() if isinstance(v, int | float | str | bool)})
        return position

    async def end_dwell(self, decision) -> None:
        """End the hold at the dwell point; the frames from here are transit; publish the estimate and log the
        ``decision``."""
        await self.vehicle.end_dwell()
        self.set_dwell(-1)
        if self.brain.estimate is not None:
            self.publish_estimate()
        self.event("decision", phase=decision.phase.value, reason=decision.reason, outcome=decision.outcome,
                   estimate=_json(self.brain.estimate))

    def publish_plan(self, decision: Decision) -> None:
        assert decision.plan is not None
        self.publish(decision.plan.to_topic(self.t))

    def publish_estimate(self) -> None:
        msg = self.brain.estimator.message(self.t)
        if msg is not None and self._put is not None:
            self.publish(msg)

    async def search(self) -> Decision:
        """The search from the airborne start to the brain's last decision (its plan None)."""
        decision = self.brain.start(self.current())
        self.decisions.append(decision)
        while decision.plan is not None and self.abort_reason is None:
            self.publish_plan(decision)
            plan = decision.plan
            d = await self.upload(plan)
            self.publish_state(decision.phase.value, f"flying to dwell point {len(self.brain.history)}: "
                                                     f"{decision.reason}")
            if not await self.arrive(d, plan.path_length() + 0.5):
                if self.abort_reason is not None:
                    break
                self.event("leg_timeout", target=d.tolist())
            self.set_dwell(len(self.brain.history))
            self.publish_state("dwell", f"dwelling at ({d[0]:.2f}, {d[1]:.2f})")
            status = await self.dwell()
            if status is None:
                break
            position = self.dwelt(d, self.dwell_index, status)
            decision = self.brain.end_dwell(position, status, self.frames.frames(), self.current())
            self.decisions.append(decision)
            await self.end_dwell(decision)
        return decision

    async def fly(self, vehicle: VehicleLink, frames: FrameSource, *, land_in_place: bool = False,
                  first_timeout_wall_s: float | None = None) -> dict:
        """The whole mission; returns its summary (reason, dwells, times, estimates)."""
        self.vehicle, self.frames = vehicle, frames
        self.publish_state("connect", "waiting for the detector's histograms")
        await self.tick(first_timeout_wall_s=first_timeout_wall_s)
        self.publish_state("takeoff", "arming and taking off")
        await vehicle.arm()  # both answered while the vehicle holds at this frame's time
        await vehicle.takeoff(self.config.altitude_m)
        await self.climb(self.config.altitude_m)
        self.t_start = self.t
        decision = await self.search()
        reason = decision.reason if self.abort_reason is None else f"search aborted: {self.abort_reason}"
        outcome = decision.outcome if self.abort_reason is None else Outcome.ABORTED
        if self.abort_reason is not None:
            self.event("abort", reason=self.abort_reason)
        self.publish_state("rtl", f"search done: {reason}")
        t_done = self.t
        try:
            if land_in_place:  # a team lands where it is: the vehicles are apart there (RTL paths may cross)
                await vehicle.land()
            else:
                await vehicle.return_to_launch()
        except ActionFailed as exc:  # a failsafe (low battery, link loss) may have taken it home already
            if await vehicle.in_air():
                raise
            self.event("rtl_refused_on_ground", result=exc.result)
        await self.landed()
        return {
            "reason": reason,
            "outcome": outcome,
            "dwell_points": len(self.brain.history),
            "search_dwell_points": self.brain.search_dwells,
            "mission_time_s": t_done - (self.t_start or 0.0),
            "flight_time_s": self.t,
            "estimate": _json(self.brain.estimate),
            "estimates": [e.to_json() for e in self.brain.estimates],
        }


def _json(estimate: SourceEstimate | None) -> dict | None:
    """An estimate as the summary and log write it (``SourceEstimate.to_json``)."""
    return None if estimate is None else estimate.to_json()
