"""The detector process: the emulated board publishing its frames over zenoh on the sim clock.

Every 100 ms of sim time (frame ``k`` = interval ``[k T, (k+1) T)``, ``detector_fw_sim.board``):

1. wait until the sim clock reaches the end of the interval;
2. wait until the true pose at the interval's end is in (``sim/truth_pose`` may arrive after the clock;
   given up after ``truth_wait_wall_s`` wall seconds without any pose), then take the true pose
   interpolated at the interval's mid-time (or the fixed ``--pose``); if none arrived within
   ``stale_after_s`` sim seconds the frame is flagged ``STALE_POSE`` and carries zero counts: the
   emulator does not know where the vehicle is, so it invents nothing;
3. draw the interval's counts from the emulator, build and encode the board frame;
4. publish the bytes on ``detector/raw`` (after any injected fault), decode them with the driver like
   any consumer, and publish the decoded ``detector/histogram`` JSON (a frame the driver rejects is
   counted and dropped; the next good one carries ``FLAG_GAP``);
5. every 1 s of sim time publish ``detector/status`` (also at once after a frame not sent, and every
   0.25 s of wall time while the clock stands still: ``DetectorProcess.publish_status``).

Fault switches for the mission tests (``FaultConfig``): corrupt or truncate raw frames at a given
rate (the driver must reject them by CRC or length), and drop-outs during which no frame is sent.
A restarted process continues the sequence at the value board time gives; its first frame carries
``FLAG_GAP`` unless it is frame 0.

The sim clock is followed, not trusted blindly: when it goes back (the vehicle was restarted while the
detector runs: its clock starts again near 0) or jumps far ahead, the process says so on stderr,
counts it (``Counters.clock_jumps``), forgets the old timeline's true poses and carries on from the
frame the clock is in now (consumers see a sequence gap). A true pose from the future (more than
``max_pose_lead_s`` past the clock) is dropped and counted like an invalid one.
"""

from __future__ import annotations

import sys
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import zenoh

from detector_fw_sim.board import Board
from detector_fw_sim.readout import CountSource, read_out, true_pose_for
from radseek import topics
from radseek.board_wire import FRAME_SIZE, FrameConsumer, encode_frame
from radseek.board_wire import frame_to_histogram as _to_histogram
from radseek.payload_drops import worth_reporting
from radseek.pose_history import PoseHistory
from radseek.simclock import Clock

if TYPE_CHECKING:
    pass


#: sim s: a true pose this far behind a frame's end is not late by a race with sim/clock (a step or two)
RACE_WINDOW_S = 1.0
#: wall s a lockstep run's detector waits, with no pose coming in, for the true pose at a frame's end (``--truth-wait``,
#: ``radseek run`` and teams). At 0.5 s a clean-clone make test's flood test (2 cores, a 100x flood of the router
#: beside the other tests) once drew one frame that differed from the unhurried flight's by one count moved one
#: channel (frame 309 of 937, all else equal); a stream that really stopped costs this wait once
#: (``TruthPoseFollower.wait_until``), and the frames made without the pose are counted (``pose_waits_given_up``)
LOCKSTEP_TRUTH_WAIT_S = 2.0

@dataclass(frozen=True)
class FaultConfig:
    """Injected faults. Rates are per-frame probabilities; drop-outs are (start, duration) in sim s."""

    corrupt_rate: float = 0.0  # flip 1-3 random bytes of the raw frame
    truncate_rate: float = 0.0  # cut the raw frame short
    dropouts: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        for name in ("corrupt_rate", "truncate_rate"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {v}")
        for t0, d in self.dropouts:
            if not (np.isfinite(t0) and np.isfinite(d) and d > 0):
                raise ValueError(f"drop-out {t0}:{d} needs a finite start and a duration > 0")

    def in_dropout(self, t0: float, t1: float) -> bool:
        """True if the frame interval [t0, t1) overlaps a drop-out."""
        return any(t0 < s + d and s < t1 for s, d in self.dropouts)


def inject(raw: bytes, faults: FaultConfig, rng: np.random.Generator) -> tuple[bytes, str]:
    """The raw frame after the configured faults, and which fault was applied ("" for none)."""
    if faults.corrupt_rate > 0 and rng.random() < faults.corrupt_rate:
        buf = bytearray(raw)
        n = int(rng.integers(1, 4))
        for i in rng.choice(len(buf), size=n, replace=False):
            buf[int(i)] ^= int(rng.integers(1, 256))
        return bytes(buf), "corrupt"
    if faults.truncate_rate > 0 and rng.random() < faults.truncate_rate:
        return raw[: int(rng.integers(1, FRAME_SIZE))], "truncate"
    return raw, ""


@dataclass(frozen=True)
class DetectorConfig:
    vehicle: str = topics.DEFAULT_VEHICLE
    stale_after_s: float = 0.5  # sim s: a true pose older than this makes frames STALE_POSE
    fixed_pose: tuple[float, float, float, float] | None = None  # x, y, z, yaw: no truth-pose topic needed
    until: float | None = None  # sim s: stop after the frame ending here (None = run until stopped)
    seed: int = 0
    faults: FaultConfig = field(default_factory=FaultConfig)
    status_period_s: float = 1.0
    max_catch_up_s: float = 10.0  # sim s: further behind than this (a clock jump), skip frames instead of bursting
    max_clock_back_s: float = 1.0  # sim s: the clock went back further than this (owner restart): resynchronise
    max_pose_lead_s: float = 5.0  # sim s: a true pose further ahead of the clock than this is dropped
    truth_wait_wall_s: float = 0.0  # wall s: a frame waits for the true pose at its end while poses flow (lockstep)


@dataclass
class Counters:
    frames: int = 0  # frames the board produced (including stale and rejected ones, excluding drop-outs)
    published: int = 0  # histograms published
    stale_frames: int = 0
    rejected: int = 0  # raw frames the driver rejected (CRC, length)
    dropout_frames: int = 0  # frames not sent during drop-outs
    bad_pose_msgs: int = 0  # truth-pose messages that failed validation or lay in the future (dropped)
    clock_jumps: int = 0  # the sim clock went back or jumped ahead: frames resumed from the new time
    emulator_errors: int = 0  # poses the physics could not evaluate (frame sent stale, zero counts)
    gaps: int = 0
    #: frames made without the true pose at their end: the wait for it (``truth_wait_wall_s``) gave up, so the frame's
    #: pose came from the poses in before it and may differ from an unhurried run's (lockstep's same-flight promise)
    pose_waits_given_up: int = 0


class TruthPoseFollower:
    """Keeps a short history of valid ``sim/truth_pose`` messages; bad messages are counted and dropped.

    Frames take the true pose interpolated at their mid-time: at 20x a frame may be produced well after
    its interval ended, and the latest pose would then place its counts further along the path."""

    def __init__(self, session: zenoh.Session, vehicle: str, counters: Counters, clock: Clock | None = None,
                 max_lead_s: float = 5.0):
        self._lock = threading.Condition()  # notified at every pose added
        self._history: PoseHistory[topics.TruthPose] = PoseHistory(keep_s=30.0)
        self._last_rx_wall: float | None = None
        self._gave_up_at: float | None = None  # _last_rx_wall when a wait last gave up
        self._counters = counters
        self._clock = clock
        self._max_lead_s = max_lead_s
        self._last_t: float | None = None
        self._step = 0.2  # the smallest spacing seen (the vehicle publishes a true pose every step, dt <= 0.2 s)
        self.holes = 0  # consecutive true poses further apart than 1.5 steps (lost messages: a diagnostic)
        self._sub = session.declare_subscriber(topics.key(topics.SIM_TRUTH_POSE, vehicle), self._on_pose)

    def _on_pose(self, sample: zenoh.Sample) -> None:
        try:
            msg = topics.TruthPose.from_bytes(sample.payload.to_bytes())
            if self._clock is not None and getattr(self._clock, "started", True) and \
                    msg.t > self._clock.now() + self._max_lead_s:
                raise topics.PayloadError(f"{topics.SIM_TRUTH_POSE}: t={msg.t:g} s lies ahead of the sim clock "
                                          f"({self._clock.now():g} s)")
        except (topics.PayloadError, TypeError) as exc:
            with self._lock:
                self._counters.bad_pose_msgs += 1
                n = self._counters.bad_pose_msgs
            if worth_reporting(n):
                print(f"radseek detector: dropped true-pose message #{n}: {exc}", file=sys.stderr, flush=True)
            return
        with self._lock:
            prev, self._last_t = self._last_t, msg.t
            gap = None if prev is None else msg.t - prev
            if gap is not None and gap > 1e-9:
                self._step = min(self._step, gap)
            hole = gap is not None and gap > 1.5 * self._step
            if hole:
                self.holes += 1
                n = self.holes
        if hole and worth_reporting(n):
            print(f"radseek detector: true-pose stream has a hole #{n}: {prev:.3f} -> {msg.t:.3f} s "
                  "(messages lost?)", file=sys.stderr, flush=True)
        with self._lock:
            self._history.add(msg)
            self._last_rx_wall = time.monotonic()
            self._lock.notify_all()

    def wait_until(self, t: float, stall_wall_s: float) -> bool:
        """Block until a true pose at or after sim time ``t`` is in, so a frame's pose does not depend on
        which messages won the race against ``sim/clock`` (the clock and the poses arrive on separate
        subscriptions, and the clock may be seen first on a loaded host). Gives up (False) as soon as no
        pose has arrived for ``stall_wall_s`` wall seconds (the stream stopped, the frame goes stale) or
        after 4 x ``stall_wall_s`` in all (poses flow but stay behind: the clock went back, an owner
        restart, which ``follow_clock`` handles next)."""
        deadline = time.monotonic() + 4 * stall_wall_s
        with self._lock:
            while True:
                last = self._history.latest()
                if last is not None and last.t >= t - 1e-6:
                    return True
                if last is not None and t - last.t > RACE_WINDOW_S:
                    return False  # not a race of a step or two: another timeline (owner restart) or a hole
                if self._last_rx_wall is None or self._last_rx_wall == self._gave_up_at:
                    return False  # nothing new since the last wait gave up: a stalled stream costs one wait
                now = time.monotonic()
                if now - self._last_rx_wall > stall_wall_s or now > deadline:
                    self._gave_up_at = self._last_rx_wall
                    return False
                self._lock.wait(0.05)

    def reset(self) -> None:
        """Forget every pose (the clock went back: they belong to the old timeline)."""
        with self._lock:
            self._last_t, self._step = None, 0.2
            self._history = PoseHistory(keep_s=30.0)

    def latest(self) -> topics.TruthPose | None:
        return self._history.latest()

    def at(self, t: float, max_gap_s: float) -> topics.TruthPose | None:
        return self._history.at(t, max_gap_s)

    def undeclare(self) -> None:
        self._sub.undeclare()


class DetectorProcess:
    """Runs the board on ``clock`` and publishes under ``radseek/<vehicle>/detector/``."""

    def __init__(self, session: zenoh.Session, clock: Clock, emulator: CountSource, config: DetectorConfig):
        self.session, self.clock, self.emulator, self.config = session, clock, emulator, config
        self.board = Board()
        self.counters = Counters()
        self.state = "starting"
        self._rng = np.random.default_rng([config.seed, 0xFA17])  # faults only; the emulator has its own
        v = config.vehicle
        self._raw_pub = topics.declare_publisher(session, topics.RAW_FRAME, v)
        self._hist_pub = topics.declare_publisher(session, topics.HISTOGRAM, v)
        self._status_pub = topics.declare_publisher(session, topics.DETECTOR_STATUS, v)
        self._poses = None if config.fixed_pose is not None else \
            TruthPoseFollower(session, v, self.counters, clock, config.max_pose_lead_s)
        self._clock_epoch = getattr(clock, "epoch", 0)
        # the first frame of this process flags a gap unless it is frame 0: earlier frames were not sent
        self._driver = FrameConsumer(first_is_gap=True)
        self.stop_event = threading.Event()
        self._last_hist_t: float | None = None

    # -- one frame -------------------------------------------------------------------------------
    def _pose_for(self, t_start: float, t_end: float) -> np.ndarray | None:
        """The true pose at the frame's mid-time; None (stale) when no pose arrived for stale_after_s."""
        if self.config.fixed_pose is not None:
            return np.asarray(self.config.fixed_pose, dtype=float)
        return true_pose_for(self._poses.latest(), self._poses.at, t_start, t_end, self.config.stale_after_s)

    def produce(self, k: int) -> None:
        """Make, publish and decode frame ``k`` (its interval has ended on the sim clock)."""
        t0, t1 = self.board.interval(k)
        if self.config.faults.in_dropout(t0, t1):
            self.counters.dropout_frames += 1
            self.state = "dropout"
            return
        if self._poses is not None and self.config.truth_wait_wall_s > 0:  # the pose at t1 may arrive after the clock
            if not self._poses.wait_until(t1, self.config.truth_wait_wall_s):
                self.counters.pose_waits_given_up += 1
        pose = self._pose_for(t0, t1)
        got = read_out(self.board, self.emulator, k, pose)
        self.state = got.state
        live, frame = got.live_time, got.frame
        if got.state != "ok":
            self.counters.stale_frames += 1
        if got.state == "emulator_error":
            self.counters.emulator_errors += 1
            if self.counters.emulator_errors == 1:
                print(f"radseek detector: emulator failed at pose {pose.tolist()} ({got.error}); "
                      "sending STALE_POSE frames for such poses", file=sys.stderr, flush=True)
        self.counters.frames += 1
        raw, _ = inject(encode_frame(frame), self.config.faults, self._rng)
        self._raw_pub.put(raw)
        self._consume(raw, t1, live)

    def _consume(self, raw: bytes, t_end: float, live: float | None = None) -> None:
        """Decode our own raw frame like any consumer and publish the histogram."""
        got = self._driver.accept(raw)
        self.counters.rejected = self._driver.stats.dropped
        if got is None:
            return
        frame, gap = got
        self.counters.gaps = self._driver.tracker.gaps if self._driver.tracker else 0
        hist = _to_histogram(frame, t=t_end, flags=gap, live_time=live, wall_time=time.time())
        self._hist_pub.put(hist.to_bytes())
        self.counters.published += 1
        self._last_hist_t = float(t_end)

    def publish_status(self, t: float) -> None:
        """``detector/status`` at ``t``: every frame ending at or before ``t`` has been handled (its
        histogram, if any, is already published). Sent every ``status_period_s`` of sim time, at once
        after a frame that was not sent (drop-out, rejected by the driver), and every 0.25 s of wall time
        while the clock does not move (a lockstep hold): the mission (``mission_process.ZenohFrames.tick``) tells a
        lost frame from a late one by it, on sim time, and a silent detector from a slow one."""
        c = self.counters
        msg = topics.DetectorStatus(t=float(t), frames=c.frames, stale_frames=c.stale_frames,
                                    crc_errors=c.rejected, state=self.state, last_histogram_t=self._last_hist_t)
        self._status_pub.put(msg.to_bytes())

    # -- the loop --------------------------------------------------------------------------------
    def follow_clock(self, k: int) -> int:
        """The frame to make next: ``k``, or the frame the clock is in now if it went back by more than
        ``max_clock_back_s`` (owner restarted) or is more than ``max_catch_up_s`` past frame ``k``'s end
        (a jump: skip ahead instead of bursting). Reported on stderr and counted."""
        now = self.clock.now()
        t0, t1 = self.board.interval(k)
        back = now < t0 - self.config.max_clock_back_s
        ahead = now - t1 > self.config.max_catch_up_s
        epoch = getattr(self.clock, "epoch", 0)
        resynced, self._clock_epoch = epoch != self._clock_epoch, epoch
        if not (back or ahead):
            return k
        new_k = self.board.index_at(now)
        self.counters.clock_jumps += 1
        self.state = "clock_jump"
        if back and self._poses is not None:
            self._poses.reset()
        print(f"radseek detector: sim clock {'went back' if back else 'jumped ahead'} "
              f"{'(resynchronised) ' if resynced else ''}from t={t0:.2f} s to t={now:.2f} s: "
              f"continuing at frame {new_k}", file=sys.stderr, flush=True)
        return new_k

    def run(self) -> Counters:
        """Produce frames on the sim clock until ``config.until`` or ``stop_event``."""
        k = self.board.index_at(self.clock.now())
        status_every = max(1, round(self.config.status_period_s / self.board.period_s))
        while not self.stop_event.is_set():
            k = self.follow_clock(k)
            t_end = self.board.interval(k)[1]
            if self.config.until is not None and t_end > self.config.until + 1e-9:
                break
            if not self.clock.sleep_until(t_end, timeout_wall_s=0.25):
                # clock stalled (owner paused, or held by lockstep) or went back: wait, never run ahead of
                # it; meanwhile say we are alive and done with every frame before k (see publish_status)
                self.publish_status(self.board.interval(k)[0])
                continue
            skip_to = self.follow_clock(k)
            if skip_to != k:  # clock jumped ahead: skip, consumers see a gap
                k = skip_to
                continue
            published = self.counters.published
            self.produce(k)
            if (k + 1) % status_every == 0 or self.counters.published == published:
                self.publish_status(t_end)  # at once for a frame not sent: the mission knows it is lost
            k += 1
        self.publish_status(self.board.interval(k)[0])  # frames before k are handled
        return self.counters

    def close(self) -> None:
        if self._poses is not None:
            self._poses.undeclare()
        for pub in (self._raw_pub, self._hist_pub, self._status_pub):
            pub.undeclare()
