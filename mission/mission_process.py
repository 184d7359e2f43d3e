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
Nothing waits forever: a frame that neither comes nor is accounted for while the vehicle stands still (lockstep
holds it at the frame's end; its histogram, or its end pose, or the statuses that would name it, dropped on the
way, say by a router whose queue to this process a flood keeps full) is declared lost after
``HELD_FRAME_WALL_S`` and the flight goes on.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zenoh

from mission.client.connection import DEFAULT_URL, connect, wait_healthy
from mission.client.vehicle_link import MavsdkVehicle
from mission.executive import FRAME_S, FlightStopped, MissionExecutive
from mission.key_accounts import DROP_KINDS, KeyAccounts
from mission.lockstep import LockstepAck
from mission.recorder import FlightRecorder, PoseHistory
from mission.search import Phase, SearchBrain, SearchConfig, reproducible
from mission.team import TeamBrain, TeamConfig
from mission.team_executive import TeamExecutive
from mission.team_link import TeamLinkBase, label_dwells
from radseek import topics
from radseek.dataset import Frames, Scenario
from radseek.frame_record import POSE_KEEP_S, FrameRecord, pose_for
from radseek.payload_drops import worth_reporting
from radseek_io.outdir import atomic_write_json

log = logging.getLogger("radseek.mission")

FRAME_TIMEOUT_WALL_S = 10.0  # wall s of detector silence (no histogram, no status) before frames are lost
POSE_WAIT_WALL_S = 2.0  # wall s a histogram waits for the pose at its end time before it is recorded anyway
STALL_WALL_S = 120.0  # wall s with neither a frame nor a pose: the stack is gone
#: wall s with neither a frame taken nor a pose step (lockstep holds the vehicle at the awaited frame's end) before
#: that frame is declared lost whatever detector/status says: its histogram or the statuses naming it were lost
HELD_FRAME_WALL_S = 30.0
TEAM_SILENT_WALL_S = 10.0  # wall s without a teammate's team/status (nor its vehicle's clock) before it is failed
#: sim s a teammate's vehicle may fly past its mission's last team/status before the mission is taken as failed:
#: under lockstep a live mission's vehicle never runs more than a frame past its ack, and the mission says it is
#: done with every frame, so a vehicle that does has had its lockstep released: its mission is gone
MATE_LAG_SIM_S = 5.0
TEAM_HEARTBEAT_WALL_S = 1.0  # wall s between repeats of the last team/status (alive while it computes or waits)
TEAM_START_WALL_S = 180.0  # wall s to wait for a teammate never heard from before it is taken as failed
TURN_POLL_WALL_S = 0.002  # wall s between looks at the teammates' statuses while waiting for this vehicle's turn
#: histograms held at most: waiting for their pose, and received but not yet taken by the flight (each queue; the
#: oldest waiting one is recorded without its pose, the oldest untaken one dropped and counted)
QUEUE_CAP = 200


@dataclass
class MissionSettings:
    url: str = DEFAULT_URL
    vehicle: str = topics.DEFAULT_VEHICLE
    seed: int = 0
    connect_timeout_s: float = 60.0
    leg_speed_m_s: float = 1.0  # expected cruise speed: a leg may take 3 x distance / speed + 30 s (sim)
    #: the team's vehicle names, this one included (``radseek run --vehicles N``); empty: a single vehicle
    team: tuple[str, ...] = ()
    #: sim seconds per wall second of the run (at most): the keys' expected rates in wall time (flood accounting);
    #: None: follow the vehicle's clock as measured from its poses (a stack started by hand)
    speedup: float | None = 1.0


class _PosedHistograms:
    """Histograms recorded with the estimated pose at their mid-time, in order: each waits in ``_pending``
    until a pose at or after its end time is in, or ``POSE_WAIT_WALL_S`` wall seconds (``_release``); what
    becomes of a released one is the subclass's ``_record``."""

    def __init__(self, drops: KeyAccounts):
        self.poses = PoseHistory(keep_s=POSE_KEEP_S)
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
        self.drops.observe_sim_time(pose.t)  # without --speedup the accounts follow the vehicle's clock
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
            if len(self._pending) > QUEUE_CAP:  # bounded: the oldest is recorded without waiting for its pose
                self._release(lambda _h, _w: len(self._pending) > QUEUE_CAP)

    def _received(self, hist: topics.Histogram, now: float):
        """Called with the lock held as ``hist`` comes in at wall time ``now``: which pending histograms are
        ready now (``ready(hist, wall_received)``)."""
        return lambda _h, w: now - w > POSE_WAIT_WALL_S

    def _release(self, ready) -> None:
        """Record the pending histograms, in order, up to the first that is not ``ready``."""
        while self._pending and ready(*self._pending[0]):
            hist, _ = self._pending.pop(0)
            self._record(hist, pose_for(hist, self.poses))

    def _record(self, hist: topics.Histogram, pose: topics.Pose | None) -> None:
        raise NotImplementedError


class _Stream(_PosedHistograms):
    """Thread-safe bridge from zenoh callbacks to the asyncio loop: poses into a history, histograms
    into a queue (every one is also recorded at once, so nothing received is lost)."""

    def __init__(self, loop: asyncio.AbstractEventLoop, recorder: FlightRecorder, accounts: KeyAccounts):
        super().__init__(accounts)  # records: the usable ones
        self.loop = loop
        self.recorder = recorder
        self.queue: asyncio.Queue[topics.Histogram] = asyncio.Queue(maxsize=QUEUE_CAP)
        self.queue_dropped = 0  # histograms dropped from a full queue (the oldest first)
        self.queue_high = 0  # the longest the queue has been
        self.dwell_index = -1
        self.latest_pose: topics.Pose | None = None
        # the lost-frame rule (ZenohFrames.tick): the latest histogram time received, the latest
        # detector/status time (every frame ending by then is handled), the wall time it last spoke
        self.hist_t = -1.0
        self.detector_t = -1.0
        self.detector_wall: float | None = None
        self.detector_hist_t = -1.0  # the latest histogram time the detector says it published
        self.write_error: OSError | None = None  # the dataset could not be written (raised by tick)

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
        try:
            usable = self.recorder.write(record)
        except OSError as exc:  # disk full, file too large: a zenoh thread cannot stop the flight, tick() does
            self.write_error = self.write_error or exc
            return
        if usable:
            self.records.append(record)
        self.loop.call_soon_threadsafe(self._enqueue, hist)

    def _enqueue(self, hist: topics.Histogram) -> None:
        """On the loop: queue ``hist`` for the flight; a full queue drops its oldest (counted, logged sparingly)."""
        if self.queue.full():
            self.queue.get_nowait()
            self.queue_dropped += 1
            if worth_reporting(self.queue_dropped, 1, 1000):
                log.warning("histogram queue full (%d): dropped the oldest untaken histogram (%d so far)",
                            QUEUE_CAP, self.queue_dropped)
        self.queue.put_nowait(hist)
        self.queue_high = max(self.queue_high, self.queue.qsize())

    def release_overdue(self) -> None:
        """Record the histograms that have waited ``POSE_WAIT_WALL_S`` for their pose. (A histogram is released on
        the next pose or histogram otherwise; under lockstep none comes while the mission waits for it, so a
        dropped pose at its end would hold it, and the flight, for ever.)"""
        now = time.monotonic()
        with self.lock:
            self._release(lambda _h, w: now - w > POSE_WAIT_WALL_S)

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

    def __init__(self, name: str, channel_edges_keV: np.ndarray, accounts: KeyAccounts):
        super().__init__(accounts)
        self.name = name
        self.edges = channel_edges_keV
        self.status: topics.TeamStatus | None = None
        self.heard_wall: float | None = None  # wall time of its last team/status (None: never heard)
        self.created_wall = time.monotonic()
        self.silent = False
        self.pose_t = -1.0  # the latest sim time of its vehicle's pose
        self.released_t = -1.0  # the latest frame time recorded (usable or not)

    def _pose(self, pose: topics.Pose) -> bool:
        self.pose_t = max(self.pose_t, pose.t)
        return self.poses.add(pose)

    def _received(self, hist: topics.Histogram, now: float):
        pose_t = self.pose_t  # a histogram whose end time's pose is in already is recorded at once
        return lambda h, w: h.t <= pose_t + 1e-6 or now - w > POSE_WAIT_WALL_S

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
        self.released_t = max(self.released_t, hist.t)
        if record.usable:
            self.records.append(record)

    def gone(self, now: float) -> str | None:
        """Why this teammate's mission is taken as gone, else None (call with the lock held)."""
        if self.status is not None and self.pose_t - self.status.t > MATE_LAG_SIM_S:
            return f"its vehicle flew {self.pose_t - self.status.t:.1f} s past its mission's last status"
        if self.heard_wall is None and now - self.created_wall > TEAM_START_WALL_S:
            return f"no team/status in {TEAM_START_WALL_S:g} s wall"
        if self.heard_wall is not None and now - self.heard_wall > TEAM_SILENT_WALL_S:
            return f"no team/status for {TEAM_SILENT_WALL_S:g} s wall"
        return None

    def frames(self) -> Frames | None:
        """Its usable frames so far, each labelled with its dwell index (-1 in transit)."""
        with self.lock:
            records = list(self.records)
            dwells = list(self.status.dwells) if self.status is not None else []
        return label_dwells(Frames.from_records(records), dwells) if records else None


class _Team(TeamLinkBase):
    """This vehicle's side of the team's zenoh traffic (``team/status`` and the joint ``estimate``)."""

    def __init__(self, session: zenoh.Session, me: str, names: tuple[str, ...], channel_edges_keV: np.ndarray,
                 accounts: KeyAccounts):
        super().__init__(me, names)
        self.mates = {n: _MateStream(n, channel_edges_keV, accounts) for n in names if n != me}
        self._subs = []
        for n, m in self.mates.items():
            self._subs += [session.declare_subscriber(topics.key(topics.POSE, n), m.on_pose),
                           session.declare_subscriber(topics.key(topics.HISTOGRAM, n), m.on_histogram),
                           session.declare_subscriber(topics.key(topics.TEAM_STATUS, n), m.on_status)]
        self._pub = topics.declare_publisher(session, topics.TEAM_STATUS, me)
        self._est_pub = topics.declare_publisher(session, topics.ESTIMATE, topics.TEAM)
        # the last status, repeated every TEAM_HEARTBEAT_WALL_S from a thread: alive while it computes or waits
        self._last: bytes | None = None
        self._send_lock = threading.Lock()
        self._stop = threading.Event()
        self._beat = threading.Thread(target=self._heartbeat, name="team-status", daemon=True)
        self._beat.start()

    # -- the carrier: zenoh
    def _send(self, msg: topics.TeamStatus) -> None:
        data = msg.to_bytes()
        with self._send_lock:
            self._last = data
            self._pub.put(data)

    def _heartbeat(self) -> None:
        while not self._stop.wait(TEAM_HEARTBEAT_WALL_S):
            with self._send_lock:
                if self._last is not None:
                    try:
                        self._pub.put(self._last)
                    except Exception:  # noqa: BLE001 - a closed session at shutdown
                        return

    def _statuses(self) -> dict[str, topics.TeamStatus]:
        out = {}
        for n, m in self.mates.items():
            with m.lock:
                if m.status is not None:
                    out[n] = m.status
        return out

    def _mate_frames(self, name: str) -> Frames | None:
        return self.mates[name].frames()

    def _gone(self, name: str) -> bool:
        m = self.mates[name]
        with m.lock:
            return m.silent or m.gone(time.monotonic()) is not None

    def lost(self) -> list[str]:
        return [n for n, m in self.mates.items() if m.silent]

    def turn_ready(self, t_next: float, frame_s: float) -> bool:
        """``TeamLinkBase.turn_ready``, and every teammate's frames up to its turn recorded here (its histograms
        and poses come on other keys than its status)."""
        if not super().turn_ready(t_next, frame_s):
            return False
        for n, m in self.mates.items():
            need = t_next if self.names.index(n) < self.index else t_next - frame_s
            with m.lock:
                behind = (m.status is not None and m.status.state != "done" and need >= frame_s - 1e-6
                          and m.released_t < need - 1e-6)  # (its first frame ends at frame_s)
                waited = m.heard_wall is not None and time.monotonic() - m.heard_wall > FRAME_TIMEOUT_WALL_S
            if behind and not waited and not self._gone(n):
                return False
        return True

    async def wait_turn(self, t_next: float, frame_s: float) -> None:
        """Look at the teammates' statuses until it is this vehicle's turn (a silent teammate is not waited for
        longer than ``TEAM_SILENT_WALL_S``: the flight then differs from run to run, as it must)."""
        while not self.turn_ready(t_next, frame_s):
            await asyncio.sleep(TURN_POLL_WALL_S)

    def publish_estimate(self, msg: topics.Estimate) -> None:
        self._est_pub.put(msg.to_bytes())

    def newly_silent(self) -> list[tuple[str, str]]:
        """Teammates whose mission is gone (once each, with why): its vehicle flew ``MATE_LAG_SIM_S`` of its sim
        time past the mission's last status (lockstep released), or nothing came for ``TEAM_SILENT_WALL_S``
        (``TEAM_START_WALL_S`` for one never heard from)."""
        now, out = time.monotonic(), []
        for n, m in self.mates.items():
            with m.lock:
                if m.silent or (m.status is not None and m.status.state == "done"):
                    continue
                why = m.gone(now)
                if why is not None:
                    m.silent = True
                    out.append((n, why))
        return out

    def close(self) -> None:
        self._stop.set()
        self._beat.join(timeout=2.0)
        for s in self._subs:
            s.undeclare()
        self._subs = []


def heard(accounts: KeyAccounts) -> str:
    """What this mission has heard so far, per key: ``pose 12 (3 dropped)``, or that it heard nothing at all (its
    session routes nothing: the router is gone or never learned its subscriptions)."""
    rows = accounts.counts()
    if not rows:
        return "heard nothing on any key"
    parts = []
    for key, row in rows.items():
        dropped = sum(row[kind] for kind in DROP_KINDS)
        parts.append(f"{topics.topic_of(key)} {row['accepted']}" + (f" ({dropped} dropped)" if dropped else ""))
    return "heard: " + ", ".join(parts)


class ZenohFrames:
    """The executive's ``FrameSource`` over zenoh: the histograms of ``stream`` taken one at a time under lockstep
    (``mission.lockstep``), with the lost-frame rule (``tick``)."""

    def __init__(self, stream: _Stream, lockstep: LockstepAck, vehicle: str, event, *,
                 held_frame_wall_s: float = HELD_FRAME_WALL_S):
        self.stream, self.lockstep, self.vehicle = stream, lockstep, vehicle
        self._event = event  # MissionExecutive.event
        self.held_frame_wall_s = held_frame_wall_s
        self._pose_t = -1.0  # the latest pose time seen
        #: wall s waited in earlier ticks, since the last frame or pose step, for frames then declared lost as held
        self._held_before = 0.0
        self.t = 0.0  # sim time of the frame being handled: the mission's "now"
        self.frame_s = FRAME_S
        self.frames_lost = 0  # frames declared lost (the pose passed their time)
        self._following_pose = False  # the detector is silent: tick on the pose until it speaks
        self._losing = False  # in a run of lost frames (logged once)

    @property
    def records(self) -> list[FrameRecord]:
        return self.stream.records

    def pose_at(self, t: float) -> topics.Pose | None:
        return self.stream.pose_at(t)

    def pose(self) -> topics.Pose | None:
        return self.stream.pose()

    def set_dwell(self, index: int) -> None:
        with self.stream.lock:
            self.stream.dwell_index = index

    def frames(self) -> Frames:
        return self.stream.frames()

    def _no_histograms(self, timeout_wall_s: float) -> FlightStopped:
        """The first frame never came: the error says where it was awaited and what this mission heard instead."""
        return FlightStopped(f"no detector histograms after {timeout_wall_s:g} s on "
                             f"{topics.key(topics.HISTOGRAM, self.vehicle)} ({heard(self.stream.drops)})")

    async def _detector_ready(self, timeout_wall_s: float) -> float:
        """Before the first ack: wait until the detector has spoken (its ``detector/status``, sent every 0.25 s
        wall while lockstep holds the clock at 0, or a histogram). Acked before it runs, the vehicle steps to the
        first frame's end, and a detector starting after that begins a frame late: under load, one of two same-seed
        runs recorded every histogram 0.1 s later than the other, and the flights differed. Returns the wall time
        left of ``timeout_wall_s``; FlightStopped when it runs out (saying what was heard)."""
        loop = asyncio.get_running_loop()
        start = loop.time()
        while self.stream.detector_wall is None and self.stream.queue.empty():
            if loop.time() - start > timeout_wall_s:
                raise self._no_histograms(timeout_wall_s)
            await asyncio.sleep(0.02)
        return max(timeout_wall_s - (loop.time() - start), 0.0)

    async def tick(self, *, first_timeout_wall_s: float | None = None) -> topics.Histogram | None:
        """Ack the frame handled last (its commands are already sent), then take the next one: its
        histogram, or None when it was lost. ``self.t`` is then the sim time of that frame's end.

        Lost, decided on sim time: ``detector/status`` says the detector is done with the frame's end and
        sent no histogram for it (its ``last_histogram_t`` is older; statuses and histograms arrive on
        separate subscriptions, so the status may overtake a histogram: such one is waited for, and
        declared lost only if it never comes within FRAME_TIMEOUT_WALL_S). Lost, decided on wall time (the flight then
        differs from run to run): the detector has been silent for FRAME_TIMEOUT_WALL_S (killed, hung)
        and the vehicle's pose has passed the frame's end; while it stays silent the mission follows
        the pose frame by frame. A detector that is alive but slow is always waited for, as long as the world
        moves or the frame is accounted for: with neither a frame nor a pose step for ``held_frame_wall_s`` (the
        vehicle held at the frame's end by lockstep, the frame's histogram or the statuses naming it lost on the
        way) the frame is lost and the flight goes on. With neither for ``STALL_WALL_S`` (across frames) the
        stack is gone: FlightStopped.
        ``first_timeout_wall_s``: a histogram is required (no loss), RuntimeError after that long."""
        stream = self.stream
        left = None if first_timeout_wall_s is None else await self._detector_ready(first_timeout_wall_s)
        self.lockstep.ack(self.t, self.frame_s)
        t_next = self.t + self.frame_s
        loop = asyncio.get_running_loop()
        start = moved = loop.time()  # moved: the last pose step seen while waiting
        in_flight_since: float | None = None
        while True:
            try:
                hist = await asyncio.wait_for(stream.queue.get(), 0.05)
            except TimeoutError:
                hist = None
            if stream.write_error is not None:  # the flight cannot be recorded: stop, naming the cause
                raise stream.write_error
            if hist is not None:
                if hist.t > self.t + 1e-6:
                    self.t, self.frame_s, self._following_pose, self._losing = hist.t, hist.duration, False, False
                self.lockstep.take(self.t)
                self._held_before = 0.0
                return hist  # (a frame older than self.t arrived after it was declared lost: handled late)
            stream.release_overdue()  # a histogram whose end pose was lost: recorded and queued without it
            now = loop.time()
            if left is not None:
                if now - start > left:
                    raise self._no_histograms(first_timeout_wall_s)
                continue
            p = stream.pose()
            if p is not None and p.t > self._pose_t:
                self._pose_t, moved, self._held_before = p.t, now, 0.0
            held = now - moved  # (the time the flight spends between ticks is not waiting: a fit may take long)
            if self._held_before + held > STALL_WALL_S:
                raise FlightStopped(f"no frame and no pose for {STALL_WALL_S:g} s wall at t={self.t:.2f} s")
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
            if not lost and held > self.held_frame_wall_s:
                lost, why = True, (f"neither it nor a pose step for {held:.1f} s wall while lockstep holds the "
                                   f"vehicle (detector/status: {fate})")
                self._held_before += held
            elif lost:
                self._held_before = 0.0
            if lost:
                if not self._losing:  # one event per run of lost frames
                    self._event("frames_lost", after=self.t, why=why)
                self._losing = True
                self.frames_lost += 1
                self.t = t_next
                self.lockstep.take(self.t)
                return None


class MissionRunner:
    """The mission process: the executive (``mission.executive``, or ``mission.team_executive`` in a team) over
    MAVSDK (``MavsdkVehicle``) and zenoh (``ZenohFrames``, and ``_Team`` for the teammates)."""

    def __init__(self, session: zenoh.Session, scenario: Scenario, out: Path, config: SearchConfig,
                 settings: MissionSettings):
        v = settings.vehicle
        self.session = session
        self.scenario = scenario
        self.out = Path(out)
        self.settings = settings
        self.team: _Team | None = None
        self.accounts = KeyAccounts(log, settings.speedup)  # every key subscribed to, teammates' included
        self._pubs = {topic: topics.declare_publisher(session, topic, v)
                      for topic in (topics.MISSION_STATE, topics.ESTIMATE, topics.PLAN)}
        kw = dict(leg_speed_m_s=settings.leg_speed_m_s, log_path=self.out / "mission_log.jsonl",
                  put=lambda topic, payload: self._pubs[topic].put(payload.to_bytes()))
        self.executive: MissionExecutive
        if len(settings.team) > 1:
            self.team = _Team(session, v, tuple(settings.team), scenario.channel_edges_keV, self.accounts)
            brain = TeamBrain(scenario, config, TeamConfig(n_vehicles=len(settings.team)), seed=settings.seed)
            self.executive = TeamExecutive(scenario, config, brain, self.team, **kw)
        else:
            self.executive = MissionExecutive(scenario, config, SearchBrain(scenario, config, seed=settings.seed),
                                              **kw)
        self.lockstep: LockstepAck | None = None

    async def run(self) -> dict:
        loop = asyncio.get_running_loop()
        ex = self.executive
        recorder = FlightRecorder(self.out, self.scenario)
        stream = _Stream(loop, recorder, self.accounts)
        v = self.settings.vehicle
        subs = [
            self.session.declare_subscriber(topics.key(topics.POSE, v), stream.on_pose),
            self.session.declare_subscriber(topics.key(topics.HISTOGRAM, v), stream.on_histogram),
            self.session.declare_subscriber(topics.key(topics.DETECTOR_STATUS, v), stream.on_status),
        ]
        wall0 = time.monotonic()
        # attached from here: a vehicle run with --lockstep holds at t = 0 until the first ack
        self.lockstep = LockstepAck(self.session, v)
        frames = ZenohFrames(stream, self.lockstep, v, ex.event)
        ex.frames = frames
        try:
            ex.publish_state("connect", f"waiting for an autopilot on {self.settings.url}")
            conn = await connect(self.settings.url, self.settings.connect_timeout_s)
            home = await wait_healthy(conn, self.settings.connect_timeout_s)
            vehicle = MavsdkVehicle(conn, on_text=lambda severity, text: ex.event("statustext", severity=severity,
                                                                                 text=text))
            ex.vehicle = vehicle
            watcher = asyncio.create_task(vehicle.watch())
            ex.event("connected", home=[home.lat_deg, home.lon_deg, home.alt_m])
            summary = await ex.fly(vehicle, frames, land_in_place=self.team is not None,
                                   first_timeout_wall_s=self.settings.connect_timeout_s)
            for sub in subs:  # stop recording before counting, so the summary matches the files
                sub.undeclare()
            subs = []
            stream.flush()
            self.lockstep.detach()  # the vehicle runs free from here (it disarms on its own)
            watcher.cancel()
            await conn.close()
            recorder.close()
            summary.update({
                "wall_time_s": time.monotonic() - wall0,
                "frames_received": recorder.received,
                "frames_recorded": recorder.recorded,
                "frames_flagged": recorder.flagged,
                "bad_payloads": self.accounts.invalid,
                "frames_lost": frames.frames_lost,
                # per key subscribed: samples accepted, dropped as a flood / as another publisher's, invalid
                "samples": self.accounts.counts(),
                "histogram_queue": {"cap": QUEUE_CAP, "high": stream.queue_high, "dropped": stream.queue_dropped},
            })
            if self.team is not None:
                summary.update(self.team.summary(ex.brain, stream.frames()))
            ex.publish_state("done", summary["reason"])
            return summary
        finally:
            for s in subs:
                s.undeclare()
            if self.team is not None:
                self.team.close()
            self.lockstep.detach()
            recorder.close()


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
