"""The mission process: MAVSDK client + zenoh subscriber + search brain + flight recorder.

Flow: connect to the autopilot (MAVSDK, ``udpin://0.0.0.0:14540`` by default), wait until healthy, arm,
take off, then loop: ask the brain for a plan, upload it as a raw mission (path waypoints, then the dwell
point as a waypoint holding for the longest dwell allowed), wait until the estimated pose has settled at
the dwell point, feed the histograms to the dwell controller until it has counted enough, end the hold
(``end_dwell``: advance the current item), hand the dwell to the brain, repeat. When the brain stops,
return to launch and land. Every histogram received is recorded with the estimated pose at its mid-time.

Only estimated poses (``pose``) and histograms reach this process; it never subscribes to ``sim/``.

Lockstep (``mission.lockstep``): the flow is driven by the histogram frames, one at a time (``_tick``):
take a frame, decide on data stamped with sim time (the frame, the estimated pose interpolated at the
frame's time, never "the latest message"), send the MAVLink commands the decision calls for, then ack
the frame on ``mission/lockstep``. A vehicle run with ``--lockstep`` does not step past the acked time
plus one frame, so a fit that takes a minute of wall time costs no sim time, and the same seed flies
the same flight. A frame the detector never sends (drop-out, rejected by the driver, restarted past
it) is declared lost when ``detector/status`` says the detector is done with the frame's time and its
histogram did not come: a decision on sim time, so a slow detector on a loaded host (alive, its status
heartbeats coming, just behind) is waited for and the recorded flight does not change. Only a *silent*
detector (killed, hung: no histogram and no status for ``FRAME_TIMEOUT_WALL_S`` wall seconds) is judged
on wall time: its frames are declared lost once the vehicle's pose has passed them, and the mission
follows the pose until the detector speaks again. That flight differs from run to run, as it must.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import zenoh

from mission.client.action import ActionFailed, Actions
from mission.client.connection import DEFAULT_URL, connect, wait_healthy
from mission.client.mission_upload import DwellPoint, MissionControl
from mission.client.telemetry import TelemetryWatch
from mission.lockstep import LockstepAck
from mission.recorder import FlightRecorder, PoseHistory
from mission.search import Decision, Phase, SearchBrain, SearchConfig, reproducible
from mission.team import TeamBrain, TeamConfig, TeamDecision, team_frames
from planner.allocation import Reservation, path_clear
from planner.belief import drift_density_from_poses
from radseek import topics
from radseek.dataset import Frames, Scenario
from radseek.frame_record import FrameRecord
from radseek.payload_drops import DropCounter
from radseek_io.outdir import atomic_write_json

log = logging.getLogger("radseek.mission")

ARRIVE_RADIUS_M = 0.12
ARRIVE_SETTLE_S = 0.5  # sim s the estimate must stay within the radius before a dwell starts
FRAME_S = 0.1  # s, the board's frame period until the first histogram says otherwise
FRAME_TIMEOUT_WALL_S = 10.0  # wall s of detector silence (no histogram, no status) before frames are lost
POSE_WAIT_WALL_S = 2.0  # wall s a histogram waits for the pose at its end time before it is recorded anyway
STALL_WALL_S = 120.0  # wall s with neither a frame nor a pose: the stack is gone
LANDED_Z_M = 0.03  # estimated altitude of a landed vehicle
TEAM_SILENT_WALL_S = 10.0  # wall s without a teammate's team/status (nor its vehicle's clock) before it is failed
#: sim s a teammate's vehicle may fly past its mission's last team/status before the mission is taken as failed:
#: under lockstep a live mission's vehicle never runs more than a frame past its ack, and the mission repeats its
#: status every TEAM_HEARTBEAT_SIM_S, so a vehicle that does has had its lockstep released: its mission is gone
MATE_LAG_SIM_S = 5.0
TEAM_HEARTBEAT_WALL_S = 1.0  # wall s between team/status repeats ...
TEAM_HEARTBEAT_SIM_S = 1.0  # ... and sim s
CLAIM_WALL_S = 0.3  # wall s a claimed reservation waits for a crossing claim made at the same time
CLAIM_ATTEMPTS = 5  # claims yielded in a row before the vehicle holds instead
TEAM_START_WALL_S = 180.0  # wall s to wait for every teammate to be airborne before the first plan


@dataclass
class MissionSettings:
    url: str = DEFAULT_URL
    vehicle: str = topics.DEFAULT_VEHICLE
    seed: int = 0
    connect_timeout_s: float = 60.0
    leg_speed_m_s: float = 1.0  # expected cruise speed: a leg may take 3 x distance / speed + 30 s (sim)
    #: the team's vehicle names, this one included (``radseek run --vehicles N``); empty: a single vehicle
    team: tuple[str, ...] = ()


async def _in_air(tel: TelemetryWatch) -> bool:
    async for v in tel._tel.subscribe_in_air():
        return bool(v)
    return False


class _PosedHistograms:
    """Histograms recorded with the estimated pose at their mid-time, in order: each waits in ``_pending``
    until a pose at or after its end time is in, or ``POSE_WAIT_WALL_S`` wall seconds (``_release``); what
    becomes of a released one is the subclass's ``_record``."""

    def __init__(self, drops: DropCounter):
        self.poses = PoseHistory(keep_s=120.0)
        self.lock = threading.Lock()
        self.records: list[FrameRecord] = []
        # histograms waiting for the pose at their end time (the pose is published before the clock that
        # makes the frame, but on another path): recorded in order once it is in, or after POSE_WAIT_WALL_S
        self._pending: list[tuple[topics.Histogram, float]] = []
        self.drops = drops

    def on_pose(self, sample: zenoh.Sample) -> None:
        pose = self.drops.decode(topics.Pose, sample)  # fails its schema or the board's limits: dropped
        if pose is None:
            return
        with self.lock:
            if self._pose(pose):
                self._release(lambda h, _w: h.t <= pose.t + 1e-6)

    def _pose(self, pose: topics.Pose) -> bool:
        """Called with the lock held: take ``pose`` into the history; True if it is on the timeline (the
        histograms pending up to its time are released)."""
        return self.poses.add(pose)

    def on_histogram(self, sample: zenoh.Sample) -> None:
        hist = self.drops.decode(topics.Histogram, sample)
        if hist is None:
            return
        now = time.monotonic()
        with self.lock:
            self._pending.append((hist, now))
            self._release(self._received(hist, now))

    def _received(self, hist: topics.Histogram, now: float):
        """Called with the lock held as ``hist`` comes in at wall time ``now``: which pending histograms are
        ready now (``ready(hist, wall_received)``)."""
        return lambda _h, w: now - w > POSE_WAIT_WALL_S

    def _release(self, ready) -> None:
        """Record the pending histograms, in order, up to the first that is not ``ready``."""
        while self._pending and ready(*self._pending[0]):
            hist, _ = self._pending.pop(0)
            self._record(hist, self.poses.at(hist.t - hist.duration / 2))

    def _record(self, hist: topics.Histogram, pose: topics.Pose | None) -> None:
        raise NotImplementedError


class _Stream(_PosedHistograms):
    """Thread-safe bridge from zenoh callbacks to the asyncio loop: poses into a history, histograms
    into a queue (every one is also recorded at once, so nothing received is lost)."""

    def __init__(self, loop: asyncio.AbstractEventLoop, recorder: FlightRecorder):
        super().__init__(DropCounter(log, "dropped invalid payload", first=10))  # records: the usable ones
        self.loop = loop
        self.recorder = recorder
        self.queue: asyncio.Queue[topics.Histogram] = asyncio.Queue()
        self.dwell_index = -1
        self.latest_pose: topics.Pose | None = None
        # the lost-frame rule (MissionRunner._tick): the latest histogram time received, the latest
        # detector/status time (every frame ending by then is handled), the wall time it last spoke
        self.hist_t = -1.0
        self.detector_t = -1.0
        self.detector_wall: float | None = None
        self.detector_hist_t = -1.0  # the latest histogram time the detector says it published

    def _pose(self, pose: topics.Pose) -> bool:
        if not self.poses.add(pose):
            return False  # out of order, or off the timeline until a second pose confirms it
        self.latest_pose = pose
        return True

    def _received(self, hist: topics.Histogram, now: float):
        self.hist_t = max(self.hist_t, hist.t)
        self.detector_wall = now
        latest = self.latest_pose
        return lambda h, w: (latest is not None and h.t <= latest.t + 1e-6) or now - w > POSE_WAIT_WALL_S

    def on_status(self, sample: zenoh.Sample) -> None:
        status = self.drops.decode(topics.DetectorStatus, sample)
        if status is None:
            return
        with self.lock:
            self.detector_t = max(self.detector_t, status.t)
            if status.last_histogram_t is not None:
                self.detector_hist_t = max(self.detector_hist_t, status.last_histogram_t)
            self.detector_wall = time.monotonic()

    def frame_fate(self, t_end: float) -> tuple[str, float | None]:
        """What became of the frame ending at ``t_end``: "received", "pending" (the detector is not done
        with it yet), "in_flight" (the detector says it sent it or a later one: the histogram is on its
        way, on another subscription than the status), "not_sent" (the detector is done with it and sent
        no histogram for it or after it); and the wall time the detector last spoke."""
        with self.lock:
            if self.hist_t >= t_end - 1e-6:
                fate = "received"
            elif self.detector_t < t_end - 1e-6:
                fate = "pending"
            elif self.detector_hist_t >= t_end - 1e-6:
                fate = "in_flight"
            else:
                fate = "not_sent"
            return fate, self.detector_wall

    def _record(self, hist: topics.Histogram, pose: topics.Pose | None) -> None:
        """Record and queue a released histogram."""
        record = FrameRecord.from_histogram(hist, pose, self.dwell_index, self.recorder.channel_edges_keV)
        if self.recorder.write(record):
            self.records.append(record)
        self.loop.call_soon_threadsafe(self.queue.put_nowait, hist)

    def flush(self) -> None:
        """Record whatever still waits for its pose (the subscriptions are closed)."""
        with self.lock:
            self._release(lambda _h, _w: True)

    def pose_at(self, t: float) -> topics.Pose | None:
        """The estimated pose at sim time ``t``, interpolated (None if none near it)."""
        with self.lock:
            return self.poses.at(t)

    def frames(self) -> Frames:
        with self.lock:
            return Frames.from_records(self.records)

    def pose(self) -> topics.Pose | None:
        with self.lock:
            return self.latest_pose


class _MateStream(_PosedHistograms):
    """A teammate's frames as its own mission records them: its histograms with its estimated pose at each
    frame's mid-time (``pose`` and ``detector/histogram`` under its name), the dwell index of each frame
    from the dwell intervals it announces (``team/status``)."""

    def __init__(self, name: str, channel_edges_keV: np.ndarray):
        super().__init__(DropCounter(log, f"dropped invalid payload from teammate {name}", first=5))
        self.name = name
        self.edges = channel_edges_keV
        self.status: topics.TeamStatus | None = None
        self.heard_wall = time.monotonic()  # (a teammate never heard from is failed after the timeout too)
        self.silent = False
        self.pose_t = -1.0  # the latest sim time of its vehicle's pose

    def _pose(self, pose: topics.Pose) -> bool:
        self.pose_t = max(self.pose_t, pose.t)
        return self.poses.add(pose)

    def on_status(self, sample: zenoh.Sample) -> None:
        msg = self.drops.decode(topics.TeamStatus, sample)
        if msg is None or msg.vehicle != self.name:
            return
        with self.lock:
            if self.status is None or msg.seq >= self.status.seq:
                self.status = msg
            self.heard_wall = time.monotonic()
            self.silent = False

    def _record(self, hist: topics.Histogram, pose: topics.Pose | None) -> None:
        record = FrameRecord.from_histogram(hist, pose, -1, self.edges)
        if record.usable:
            self.records.append(record)

    def frames(self) -> Frames | None:
        """Its usable frames so far, each labelled with its dwell index (-1 in transit)."""
        with self.lock:
            records = list(self.records)
            dwells = list(self.status.dwells) if self.status is not None else []
        if not records:
            return None
        f = Frames.from_records(records)
        dwell = np.full(len(f), -1)
        for d in dwells:
            dwell[(f.t >= d["t_first"] - 1e-6) & (f.t <= d["t_last"] + 1e-6)] = int(d["index"])
        f.dwell[:] = dwell
        return f


class _Team:
    """This vehicle's side of the team's zenoh traffic (``team/status`` and the joint ``estimate``)."""

    def __init__(self, session: zenoh.Session, me: str, names: tuple[str, ...], channel_edges_keV: np.ndarray):
        if me not in names:
            raise ValueError(f"vehicle {me!r} is not one of the team {names}")
        self.me, self.names, self.index = me, names, names.index(me)
        self.mates = {n: _MateStream(n, channel_edges_keV) for n in names if n != me}
        self._subs = []
        for n, m in self.mates.items():
            self._subs += [session.declare_subscriber(topics.key(topics.POSE, n), m.on_pose),
                           session.declare_subscriber(topics.key(topics.HISTOGRAM, n), m.on_histogram),
                           session.declare_subscriber(topics.key(topics.TEAM_STATUS, n), m.on_status)]
        self._pub = topics.declare_publisher(session, topics.TEAM_STATUS, me)
        self._est_pub = topics.declare_publisher(session, topics.ESTIMATE, topics.TEAM)
        self.seq = 0
        self.state = "start"
        self.reservation = np.zeros((1, 3))
        self.var_xy = 0.0
        self.stamp = 0.0
        self.dwells: list[dict[str, float]] = []
        self.flown = np.zeros((0, 3))
        self.reason = ""
        self.decided = False
        self.t = 0.0
        self._sent_wall = -math.inf
        self._sent_t = -math.inf
        self._taken = {n: 0 for n in self.mates}  # teammates' dwells already handed to the brain
        self._flown_taken = {n: 0 for n in self.mates}

    # -- publishing
    def _put(self) -> None:
        msg = topics.TeamStatus(t=self.t, vehicle=self.me, seq=self.seq, state=self.state,
                                reservation=self.reservation.tolist(), dwells=self.dwells,
                                flown=self.flown[::4].tolist(), reason=self.reason, decided=self.decided,
                                stamp=self.stamp, var_xy=self.var_xy)
        self.seq += 1
        self._pub.put(msg.to_bytes())
        self._sent_wall, self._sent_t = time.monotonic(), self.t

    def set(self, t: float, state: str, reservation: np.ndarray, var_xy: float | None = None) -> None:
        self.t, self.state = float(t), state
        self.reservation = np.asarray(reservation, dtype=float).reshape(-1, 3)
        if var_xy is not None:
            self.var_xy = max(float(var_xy), 0.0)
        self._put()

    def claim(self, t: float, path: np.ndarray, var_xy: float) -> float:
        """Announce the plan's path as this vehicle's reservation; returns the claim's stamp."""
        self.stamp = time.time()
        self.set(t, "fly", path, var_xy)
        return self.stamp

    def add_dwell(self, index: int, position: np.ndarray, mean_rate: float, t_first: float, t_last: float,
                  flown: np.ndarray) -> None:
        rate = float(mean_rate) if math.isfinite(mean_rate) else 0.0
        self.dwells.append({"index": int(index), "x": float(position[0]), "y": float(position[1]),
                            "z": float(position[2]), "mean_rate": rate, "t_first": float(t_first),
                            "t_last": float(t_last)})
        if len(flown):
            self.flown = np.vstack([self.flown, flown])

    def finish(self, t: float, reason: str, decided: bool) -> None:
        self.reason, self.decided = reason, decided
        self.set(t, "done", self.reservation[-1:])

    def heartbeat(self, t: float) -> None:
        """Repeat the status every TEAM_HEARTBEAT_WALL_S wall and TEAM_HEARTBEAT_SIM_S sim seconds (once it has
        said where it is)."""
        self.t = max(self.t, float(t))
        if self.seq and (time.monotonic() - self._sent_wall > TEAM_HEARTBEAT_WALL_S or
                         self.t - self._sent_t >= TEAM_HEARTBEAT_SIM_S):
            self._put()

    def publish_estimate(self, payload: bytes) -> None:
        self._est_pub.put(payload)

    # -- what the teammates say
    def _statuses(self) -> dict[str, topics.TeamStatus]:
        out = {}
        for n, m in self.mates.items():
            with m.lock:
                if m.status is not None:
                    out[n] = m.status
        return out

    def reserved(self) -> dict[int, Reservation]:
        """Every teammate's last reservation by team index (a failed teammate's stays: where it was last)."""
        return {self.names.index(n): Reservation(np.asarray(st.reservation, dtype=float), st.var_xy)
                for n, st in self._statuses().items()}

    def earlier_crossing(self, path: np.ndarray, stamp: float, separation: float, var_xy: float) -> str | None:
        """A teammate whose reservation crosses ``path`` and was claimed before ``stamp`` (this claim yields)."""
        for n, st in self._statuses().items():
            mate = Reservation(np.asarray(st.reservation, dtype=float), st.var_xy)
            if st.state == "fly" and (st.stamp, self.names.index(n)) < (stamp, self.index) and \
                    not path_clear(path, [mate], separation, var_xy):
                return n
        return None

    def over(self) -> str | None:
        """The reason the team's search ended, when a teammate's estimate ended it."""
        for n, st in self._statuses().items():
            if st.state == "done" and st.decided:
                return f"{st.reason} (decided by {n})"
        return None

    def newly_silent(self) -> list[tuple[str, str]]:
        """Teammates whose mission is gone (once each, with why): its vehicle flew ``MATE_LAG_SIM_S`` of its sim
        time past the mission's last status (lockstep released), or nothing came for ``TEAM_SILENT_WALL_S``."""
        now, out = time.monotonic(), []
        for n, m in self.mates.items():
            with m.lock:
                if m.silent or (m.status is not None and m.status.state == "done"):
                    continue
                why = None
                if m.status is not None and m.pose_t - m.status.t > MATE_LAG_SIM_S:
                    why = f"its vehicle flew {m.pose_t - m.status.t:.1f} s past its mission's last status"
                elif now - m.heard_wall > TEAM_SILENT_WALL_S:
                    why = f"no team/status for {TEAM_SILENT_WALL_S:g} s wall"
                if why is not None:
                    m.silent = True
                    out.append((n, why))
        return out

    def new_dwells(self) -> list[tuple[int, dict, np.ndarray | None]]:
        """Teammates' dwells not yet handed to the brain, with the path each flew since its last."""
        out = []
        for n, st in self._statuses().items():
            new = st.dwells[self._taken[n]:]
            if not new:
                continue
            self._taken[n] = len(st.dwells)
            flown = np.asarray(st.flown, dtype=float).reshape(-1, 3)
            path, self._flown_taken[n] = flown[self._flown_taken[n]:], len(flown)
            for k, d in enumerate(new):
                out.append((self.names.index(n), d, path if k == 0 else None))
        return out

    def frames(self, own: Frames) -> Frames:
        """The team's frames (``mission.team.team_frames``): this vehicle's and every teammate's so far."""
        per = [own if n == self.me else self.mates[n].frames() for n in self.names]
        return team_frames(per)

    def summary(self, brain: SearchBrain, own: Frames) -> dict:
        step = np.linalg.norm(np.diff(own.positions, axis=0), axis=1) if len(own) > 1 else np.zeros(0)
        moving = own.dwell[1:] < 0 if len(own) > 1 else np.zeros(0, dtype=bool)
        return {"vehicle": self.me, "team": list(self.names), "decided": self.decided,
                "distance_m": float(step[moving].sum()), "own_dwell_points": len(self.dwells),
                "teammates_lost": [n for n, m in self.mates.items() if m.silent]}

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        self._subs = []


class MissionRunner:
    def __init__(self, session: zenoh.Session, scenario: Scenario, out: Path, config: SearchConfig,
                 settings: MissionSettings):
        self.session = session
        self.scenario = scenario
        self.out = Path(out)
        self.config = config
        self.settings = settings
        v = settings.vehicle
        self.team: _Team | None = None
        if len(settings.team) > 1:
            self.team = _Team(session, v, tuple(settings.team), scenario.channel_edges_keV)
            self.brain: SearchBrain = TeamBrain(scenario, config, TeamConfig(n_vehicles=len(settings.team)),
                                                seed=settings.seed)
        else:
            self.brain = SearchBrain(scenario, config, seed=settings.seed)
        self._state_pub = topics.declare_publisher(session, topics.MISSION_STATE, v)
        self._est_pub = topics.declare_publisher(session, topics.ESTIMATE, v)
        self._plan_pub = topics.declare_publisher(session, topics.PLAN, v)
        self.log: list[dict] = []
        self.t_start: float | None = None
        self.battery = math.nan
        self.abort_reason: str | None = None  # set when the vehicle leaves the search (failsafe, landed)
        self.airborne = False
        self.t = 0.0  # sim time of the frame being handled: the mission's "now"
        self.frame_s = FRAME_S
        self.frames_lost = 0  # frames declared lost by the lockstep pump (the pose passed their time)
        self._following_pose = False  # the detector is silent: tick on the pose until it speaks
        self._losing = False  # in a run of lost frames (logged once)
        self.lockstep: LockstepAck | None = None

    async def _watch(self, tel: TelemetryWatch, stream: _Stream) -> None:
        """Background: keep the battery level and log every STATUSTEXT (failsafes say why here)."""

        async def battery() -> None:
            async for b in tel._tel.subscribe_battery():
                self.battery = float(b.remaining_percent) / (100.0 if b.remaining_percent > 1.0 else 1.0)

        async def texts() -> None:
            async for severity, text in tel.status_texts():
                self._event(stream, "statustext", severity=severity, text=text)
                if text.lower().startswith("failsafe") and self.abort_reason is None:
                    self.abort_reason = f"vehicle failsafe: {text}"

        async def in_air() -> None:
            async for flying in tel._tel.subscribe_in_air():
                if self.airborne and not flying and self.abort_reason is None:
                    self.abort_reason = "vehicle landed"
                self.airborne = self.airborne or flying

        await asyncio.gather(battery(), texts(), in_air())

    # ------------------------------------------------------------------------------ publishing

    def _now(self, stream: _Stream) -> float:
        return self.t

    # ------------------------------------------------------------------------------ lockstep pump

    async def _tick(self, stream: _Stream, *, first_timeout_wall_s: float | None = None) -> topics.Histogram | None:
        """Ack the frame handled last (its commands are already sent), then take the next one: its
        histogram, or None when it was lost. ``self.t`` is then the sim time of that frame's end.

        Lost, decided on sim time: ``detector/status`` says the detector is done with the frame's end and
        sent no histogram for it (its ``last_histogram_t`` is older; statuses and histograms arrive on
        separate subscriptions, so the status may overtake a histogram: such one is waited for, and
        declared lost only if it never comes within FRAME_TIMEOUT_WALL_S). Lost, decided on wall time (the flight then
        differs from run to run): the detector has been silent for FRAME_TIMEOUT_WALL_S (killed, hung)
        and the vehicle's pose has passed the frame's end; while it stays silent the mission follows
        the pose frame by frame. A detector that is alive but slow is always waited for.
        ``first_timeout_wall_s``: a histogram is required (no loss), RuntimeError after that long."""
        if self.lockstep is not None:
            self.lockstep.ack(self.t, self.frame_s)
        if self.team is not None:
            self._team_heartbeat(stream)
        t_next = self.t + self.frame_s
        loop = asyncio.get_running_loop()
        start = last_pose_at = loop.time()
        last_pose_t = -1.0
        in_flight_since: float | None = None
        while True:
            try:
                hist = await asyncio.wait_for(stream.queue.get(), 0.05)
            except TimeoutError:
                hist = None
            if hist is not None:
                if hist.t > self.t + 1e-6:
                    self.t, self.frame_s, self._following_pose, self._losing = hist.t, hist.duration, False, False
                if self.lockstep is not None:
                    self.lockstep.take(self.t)
                return hist  # (a frame older than self.t arrived after it was declared lost: handled late)
            now = loop.time()
            if first_timeout_wall_s is not None:
                if now - start > first_timeout_wall_s:
                    raise RuntimeError(f"no detector histograms after {first_timeout_wall_s:g} s on "
                                       f"{topics.key(topics.HISTOGRAM, self.settings.vehicle)}")
                continue
            p = stream.pose()
            if p is not None and p.t > last_pose_t:
                last_pose_t, last_pose_at = p.t, now
            if now - last_pose_at > STALL_WALL_S:
                raise RuntimeError(f"no frame and no pose for {STALL_WALL_S:g} s wall at t={self.t:.2f} s")
            fate, spoke_wall = stream.frame_fate(t_next)
            lost, why = fate == "not_sent", "not sent (detector/status)"
            if fate == "in_flight":  # sent, yet not here: zenoh dropped it (wall time: a real loss)
                in_flight_since = now if in_flight_since is None else in_flight_since
                lost, why = now - in_flight_since > FRAME_TIMEOUT_WALL_S, "sent but never received"
            if not lost and fate != "in_flight":
                # (loop.time() is time.monotonic() on the default loop, as the stream's wall stamps)
                silent = now - (start if spoke_wall is None else spoke_wall)
                passed = p is not None and p.t >= t_next - 1e-6
                lost = passed and (silent > FRAME_TIMEOUT_WALL_S or (self._following_pose and silent > 1.0))
                why = f"detector silent for {silent:.1f} s wall"
                self._following_pose = self._following_pose or lost
            if lost:
                if not self._losing:  # one event per run of lost frames
                    self._event(stream, "frames_lost", after=self.t, why=why)
                self._losing = True
                self.frames_lost += 1
                self.t = t_next
                if self.lockstep is not None:
                    self.lockstep.take(self.t)
                return None

    def publish_state(self, stream: _Stream, phase: str, progress: str) -> None:
        msg = topics.MissionState(t=self._now(stream), phase=phase, dwell_index=stream.dwell_index,
                                  battery=1.0 if math.isnan(self.battery) else self.battery, progress=progress)
        self._state_pub.put(msg.to_bytes())

    def _event(self, stream: _Stream, kind: str, **fields) -> None:
        entry = {"t": self._now(stream), "event": kind, **fields}
        self.log.append(entry)
        with open(self.out / "mission_log.jsonl", "a") as fh:
            fh.write(json.dumps(entry) + "\n")

    # ------------------------------------------------------------------------------ flying

    async def _arrive(self, stream: _Stream, target: np.ndarray, path_length: float) -> bool:
        """Frame by frame until the estimated position (at each frame's time) has stayed within
        ARRIVE_RADIUS_M of target for ARRIVE_SETTLE_S of sim time; False after 3 x the expected flight
        time + 30 s of sim time, or when the vehicle left the search (failsafe, landed)."""
        t0 = self.t
        limit = 3.0 * path_length / self.settings.leg_speed_m_s + 30.0
        inside_since: float | None = None
        while self.t - t0 < limit and self.abort_reason is None and self._team_over() is None:
            await self._tick(stream)
            p = stream.pose_at(self.t)
            if p is not None:
                if math.dist((p.x, p.y, p.z), target[:3]) < ARRIVE_RADIUS_M:
                    inside_since = self.t if inside_since is None else inside_since
                    if self.t - inside_since >= ARRIVE_SETTLE_S:
                        return True
                else:
                    inside_since = None
        return False

    async def _dwell(self, stream: _Stream):
        """Feed the frames after arrival (their interval starts there: frames integrated while still
        moving do not count) to the dwell controller until it is satisfied (None if the vehicle left
        the search meanwhile)."""
        self.brain.begin_dwell()
        while self.abort_reason is None and self._team_over() is None:
            hist = await self._tick(stream)
            if hist is None:
                continue
            status = self.brain.on_frame(hist)
            if status.done:
                return status
        return None

    async def _climb(self, stream: _Stream, altitude: float, limit_s: float = 120.0) -> None:
        """Frame by frame until the estimated altitude is within 0.2 m of ``altitude``."""
        t0 = self.t
        while True:
            await self._tick(stream)
            p = stream.pose_at(self.t)
            if p is not None and p.z > altitude - 0.2:
                return
            if self.t - t0 > limit_s:
                raise RuntimeError(f"takeoff: {altitude:g} m not reached in {limit_s:g} s of sim time")

    async def _landed(self, stream: _Stream, limit_s: float = 600.0) -> None:
        """Frame by frame until the estimated pose has stayed on the ground for ARRIVE_SETTLE_S."""
        t0 = self.t
        down_since: float | None = None
        while True:
            p = stream.pose_at(self.t)
            if p is not None and p.z <= LANDED_Z_M:
                down_since = self.t if down_since is None else down_since
                if self.t - down_since >= ARRIVE_SETTLE_S:
                    return
            else:
                down_since = None
            if self.t - t0 > limit_s:
                raise RuntimeError(f"not landed {limit_s:g} s of sim time after the return to launch")
            await self._tick(stream)

    async def run(self) -> dict:
        loop = asyncio.get_running_loop()
        recorder = FlightRecorder(self.out, self.scenario)
        stream = _Stream(loop, recorder)
        v = self.settings.vehicle
        subs = [
            self.session.declare_subscriber(topics.key(topics.POSE, v), stream.on_pose),
            self.session.declare_subscriber(topics.key(topics.HISTOGRAM, v), stream.on_histogram),
            self.session.declare_subscriber(topics.key(topics.DETECTOR_STATUS, v), stream.on_status),
        ]
        wall0 = time.monotonic()
        # attached from here: a vehicle run with --lockstep holds at t = 0 until the first ack
        self.lockstep = LockstepAck(self.session, v)
        try:
            self.publish_state(stream, "connect", f"waiting for an autopilot on {self.settings.url}")
            conn = await connect(self.settings.url, self.settings.connect_timeout_s)
            home = await wait_healthy(conn, self.settings.connect_timeout_s)
            actions, mission, tel = Actions(conn), MissionControl(conn), TelemetryWatch(conn)
            watcher = asyncio.create_task(self._watch(tel, stream))
            self._event(stream, "connected", home=[home.lat_deg, home.lon_deg, home.alt_m])
            self.publish_state(stream, "connect", "waiting for the detector's histograms")
            await self._tick(stream, first_timeout_wall_s=self.settings.connect_timeout_s)
            self.publish_state(stream, "takeoff", "arming and taking off")
            await actions.arm()  # both answered while the vehicle holds at this frame's time
            await actions.takeoff(self.config.altitude_m)
            await self._climb(stream, self.config.altitude_m)
            self.t_start = self.t
            current = self._current(stream)
            if self.team is not None:  # the team's search (mission.team): decided jointly, flown here
                decision = await self._fly_team(stream, mission)
            else:
                decision = self.brain.start(current)
            while decision.plan is not None and self.abort_reason is None:
                self._publish_plan(stream, decision)
                plan = decision.plan
                d = await self._upload(mission, plan)
                self.publish_state(stream, decision.phase.value,
                                   f"flying to dwell point {len(self.brain.history)}: {decision.reason}")
                if not await self._arrive(stream, d, plan.path_length() + 0.5):
                    if self.abort_reason is not None:
                        break
                    self._event(stream, "leg_timeout", target=d.tolist())
                with stream.lock:
                    stream.dwell_index = len(self.brain.history)
                self.publish_state(stream, "dwell", f"dwelling at ({d[0]:.2f}, {d[1]:.2f})")
                status = await self._dwell(stream)
                if status is None:
                    break
                position = self._dwelt(stream, d, stream.dwell_index, status)
                decision = self.brain.end_dwell(position, status, stream.frames(), self._current(stream))
                await self._end_dwell(stream, mission, decision)
            reason = decision.reason if self.abort_reason is None else f"search aborted: {self.abort_reason}"
            if self.abort_reason is not None:
                self._event(stream, "abort", reason=self.abort_reason)
            self.publish_state(stream, "rtl", f"search done: {reason}")
            t_done = self._now(stream)
            try:
                if self.team is not None:  # land where it is: the vehicles are apart there (RTL paths may cross)
                    await actions.land()
                else:
                    await actions.return_to_launch()
            except ActionFailed as exc:
                # a failsafe (low battery, link loss) may have taken the vehicle home already
                if await _in_air(tel):
                    raise
                self._event(stream, "rtl_refused_on_ground", result=exc.result)
            await self._landed(stream)
            t_landed = self.t
            for sub in subs:  # stop recording before counting, so the summary matches the files
                sub.undeclare()
            subs = []
            stream.flush()
            self.lockstep.detach()  # the vehicle runs free from here (it disarms on its own)
            watcher.cancel()
            await conn.close()
            recorder.close()
            summary = {
                "reason": reason,
                "dwell_points": len(self.brain.history),
                "search_dwell_points": self.brain.search_dwells,
                "mission_time_s": t_done - (self.t_start or 0.0),
                "flight_time_s": t_landed,
                "wall_time_s": time.monotonic() - wall0,
                "estimate": self.brain.estimate,
                "estimates": self.brain.estimates,
                "frames_received": recorder.received,
                "frames_recorded": recorder.recorded,
                "frames_flagged": recorder.flagged,
                "bad_payloads": stream.drops.count,
                "frames_lost": self.frames_lost,
            }
            if self.team is not None:
                summary.update(self.team.summary(self.brain, stream.frames()))
            self.publish_state(stream, "done", summary["reason"])
            return summary
        finally:
            for s in subs:
                s.undeclare()
            if self.team is not None:
                self.team.close()
            self.lockstep.detach()
            recorder.close()

    async def _upload(self, mission: MissionControl, plan) -> np.ndarray:
        """Fly ``plan``: its path as pass-through waypoints, then its dwell point holding for the longest dwell
        allowed, from the new first item; returns the dwell point."""
        points = [DwellPoint(*p[:3], yaw=p[3], max_dwell_s=0.0) for p in plan.path[1:-1]]
        d = plan.dwell_points[0]
        points.append(DwellPoint(*d[:3], yaw=d[3], max_dwell_s=self.config.dwell.t_timeout + 30.0))
        await mission.replace_remaining(points)
        await mission.start()  # (re)enter AUTO.MISSION at the new first item
        return d

    def _dwelt(self, stream: _Stream, d: np.ndarray, index: int, status) -> np.ndarray:
        """Where dwell ``index`` (at dwell point ``d``) was measured: the estimated pose now (else ``d``), logged
        with the dwell's ``status``."""
        p = stream.pose_at(self.t)
        position = np.array([p.x, p.y, p.z]) if p is not None else d[:3]
        self._event(stream, "dwell", index=index, position=position.tolist(),
                    **{k: v for k, v in asdict(status).items() if isinstance(v, int | float | str | bool)})
        return position

    async def _end_dwell(self, stream: _Stream, mission: MissionControl, decision) -> None:
        """End the hold at the dwell point; the frames from here are transit; publish the estimate and log the
        ``decision``."""
        await mission.end_dwell()
        with stream.lock:
            stream.dwell_index = -1
        if self.brain.estimate is not None:
            self._publish_estimate(stream)
        self._event(stream, "decision", phase=decision.phase.value, reason=decision.reason,
                    estimate=self.brain.estimate)

    def _current(self, stream: _Stream) -> np.ndarray:
        p = stream.pose_at(self.t)
        if p is None:
            return np.array([0.0, 0.0, self.config.altitude_m, 0.0])
        return np.array([p.x, p.y, p.z, p.yaw])

    def _publish_plan(self, stream: _Stream, decision: Decision) -> None:
        assert decision.plan is not None
        self._plan_pub.put(decision.plan.to_topic(self._now(stream)).to_bytes())

    def _publish_estimate(self, stream: _Stream) -> None:
        loc = self.brain.localizer
        if loc is not None:
            payload = loc.to_estimate(self._now(stream)).to_bytes()
            self._est_pub.put(payload)
            if self.team is not None:  # the joint estimate, on the team's one key
                self.team.publish_estimate(payload)

    # ------------------------------------------------------------------------------ team (mission.team)

    def _team_over(self) -> str | None:
        """Why the team's search is over (a teammate's estimate ended it), else None; always None alone."""
        return None if self.team is None else self.team.over()

    def _team_heartbeat(self, stream: _Stream) -> None:
        assert self.team is not None
        self.team.heartbeat(self.t)
        for name, why in self.team.newly_silent():
            self._event(stream, "teammate_lost", vehicle=name, why=why)

    def _ingest_team(self) -> None:
        """Hand the teammates' newly announced dwells to the team brain."""
        assert self.team is not None and isinstance(self.brain, TeamBrain)
        for index, dwell, flown in self.team.new_dwells():
            self.brain.add_dwell(index, np.array([dwell["x"], dwell["y"], dwell["z"]]), dwell["mean_rate"], flown)

    async def _claim(self, stream: _Stream, decide, first: TeamDecision | None = None) -> TeamDecision:
        """Decide (``decide()`` -> TeamDecision) and claim the plan's reservation: publish it, wait
        ``CLAIM_WALL_S`` of wall time (lockstep holds sim time) for a teammate's claim made at the same time,
        and plan again if an earlier claim crosses this one (``mission.team``'s allocation rule, made safe
        between processes: of two crossing claims the later one yields)."""
        assert self.team is not None
        team = self.team
        for attempt in range(CLAIM_ATTEMPTS):
            self._ingest_team()
            self._own_pose_variance(stream)
            decision = first if attempt == 0 and first is not None else decide()
            if decision.plan is None:
                return decision
            path = decision.plan.path[:, :3]
            var_end = self.brain.var_at_end(team.index, path)
            stamp = team.claim(self.t, path, var_end)
            await asyncio.sleep(CLAIM_WALL_S)
            crossing = team.earlier_crossing(path, stamp, self.brain.team.separation_m, var_end)
            if crossing is None:
                return decision
            self._event(stream, "yield", to=crossing, attempt=attempt)
            team.set(self.t, "hold", self._current(stream)[None, :3])
        return TeamDecision(self.team.index, self.brain.phase, None, "hold: claims kept crossing",
                            self.brain.team.hold_s)

    def _own_pose_variance(self, stream: _Stream) -> tuple[float, float]:
        """This vehicle's reported x-y pose variance now and its growth per metre flown (from its frames),
        handed to the team brain for the drift margin of its next path."""
        assert self.team is not None and isinstance(self.brain, TeamBrain)
        p = stream.pose_at(self.t) or stream.pose()
        f = stream.frames()
        var = float(p.var_x) if p is not None and math.isfinite(p.var_x) else 0.0
        density = float(drift_density_from_poses(f.positions, f.pose_variances, f.dwell)[0]) if len(f) > 1 else 0.0
        self.brain.set_pose_variance(self.team.index, var, density)
        return var, density

    async def _fly_team(self, stream: _Stream, mission: MissionControl) -> Decision:
        """The team's search from this vehicle: plans from the team brain (every vehicle's dwells and frames),
        reservations claimed on ``team/status``; returns the final decision (the plan None)."""
        assert self.team is not None and isinstance(self.brain, TeamBrain)
        team, brain, me = self.team, self.brain, self.team.index
        current = self._current(stream)
        team.set(self.t, "start", np.r_[current[:2], self.config.altitude_m][None, :],
                 self._own_pose_variance(stream)[0])
        # no plan before every teammate has said where it is (airborne at its launch point), or is given up
        # on: the wait is in wall time, while lockstep holds sim time, so it costs no flight time
        waited = time.monotonic()
        while len(team.reserved()) < len(team.mates) and time.monotonic() - waited < TEAM_START_WALL_S:
            team.heartbeat(self.t)
            await asyncio.sleep(0.05)
        missing = [n for n in team.mates if self.team.names.index(n) not in team.reserved()]
        if missing:
            self._event(stream, "teammates_missing_at_start", vehicles=missing)
        decision = await self._claim(stream, lambda: brain.start(self._current(stream), me, team.reserved()))
        own_dwells = 0
        while self.abort_reason is None:
            over = team.over()
            if over is not None:
                return Decision(Phase.DONE, None, over)
            if decision.done:
                team.finish(self.t, decision.reason, decided=True)
                return decision.as_decision()
            if decision.retire:  # boxed in by the teammates for long: this vehicle leaves, the team goes on
                team.finish(self.t, decision.reason, decided=False)
                return decision.as_decision()
            if decision.plan is None:  # hold where it is, then ask again
                here = self._current(stream)
                team.set(self.t, "hold", here[None, :3])
                self.publish_state(stream, "hold", decision.reason)
                t_end = self.t + decision.hold_s
                while self.t < t_end - 1e-6 and self.abort_reason is None and team.over() is None:
                    await self._tick(stream)
                decision = await self._claim(stream, lambda: brain.replan(me, self._current(stream), team.reserved()))
                continue
            self._publish_plan(stream, decision.as_decision())
            plan = decision.plan
            d = await self._upload(mission, plan)
            self.publish_state(stream, decision.phase.value, f"flying to dwell point {own_dwells}: {decision.reason}")
            first_frame = len(stream.records)
            if not await self._arrive(stream, d, plan.path_length() + 0.5):
                if self.abort_reason is not None or team.over() is not None:
                    continue
                self._event(stream, "leg_timeout", target=d.tolist())
            with stream.lock:
                stream.dwell_index = own_dwells
            team.set(self.t, "dwell", d[None, :3])
            self.publish_state(stream, "dwell", f"dwelling at ({d[0]:.2f}, {d[1]:.2f})")
            status = await self._dwell(stream)
            if status is None:
                continue
            position = self._dwelt(stream, d, own_dwells, status)
            with stream.lock:
                records = list(stream.records)
            times = [r.t for r in records if r.dwell == own_dwells]
            flown = np.array([(r.x, r.y, r.z) for r in records[first_frame:] if r.dwell < 0]).reshape(-1, 3)
            team.add_dwell(own_dwells, position, status.mean_rate, min(times, default=self.t),
                           max(times, default=self.t), flown)
            self._ingest_team()
            frames = team.frames(stream.frames())
            self._own_pose_variance(stream)
            decision = brain.end_dwell(position, status, frames, self._current(stream), flown, me, team.reserved())
            if decision.plan is not None:  # claim it (and plan again if an earlier claim crosses it)
                decision = await self._claim(stream, lambda: brain.replan(me, self._current(stream), team.reserved()),
                                             first=decision)
            await self._end_dwell(stream, mission, decision)
            own_dwells += 1
        team.finish(self.t, f"search aborted: {self.abort_reason}", decided=False)
        return Decision(Phase.DONE, None, f"search aborted: {self.abort_reason}")


def run_mission(session: zenoh.Session, scenario: Scenario, out: Path, config: SearchConfig | None = None,
                settings: MissionSettings | None = None) -> dict:
    from planner.dwell_tree import seed_ompl

    settings = settings or MissionSettings()
    seed_ompl(settings.seed + 1)  # OMPL's random trees follow the mission's seed (OMPL refuses seed 0)
    runner = MissionRunner(session, scenario, out, reproducible(config or SearchConfig()), settings)
    summary = asyncio.run(runner.run())
    atomic_write_json(Path(out) / "mission_summary.json", summary)  # whole or not at all
    return summary


__all__ = ["MissionRunner", "MissionSettings", "Phase", "run_mission"]
