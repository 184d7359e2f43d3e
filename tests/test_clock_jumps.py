"""The sim clock is followed, not trusted blindly (issue 12): a `sim/clock` sample that jumps far ahead
or back is reported and dropped unless the owner confirms the new timeline, and a restarted owner
(clock near 0 again) resynchronises a running detector instead of stalling it silently.

A real `radseek detector` process follows a clock the test publishes over a real zenoh router on
loopback; the test plays the vehicle (sim/clock and sim/truth_pose every 0.05 s of sim time). Every
assertion is on events and sim time; wall time only bounds waiting, generously."""

from __future__ import annotations

import json
import math
import re
import threading
import time

import pytest

from radseek import topics
from radseek.simclock import ClockPublisher, ZenohClock
from radseek.zenoh_session import open_session
from tests.test_detector_stream import Proc

WAIT_S = 120.0
STEP_S = 0.05  # sim s per owner step
pytestmark = pytest.mark.timeout(600)


class Owner:
    """The test's vehicle: sim/clock and sim/truth_pose every STEP_S of sim time at about 10x (sim/truth_pose only up
    to ``poses_until``: the truth stream stops there while the clock goes on)."""

    def __init__(self, session, poses_until: float = math.inf):
        self.poses_until = poses_until
        self.clock = ClockPublisher(session, "uav0", 10.0)
        self.raw_clock = session.declare_publisher(topics.key(topics.SIM_CLOCK))
        self.truth = session.declare_publisher(topics.key(topics.SIM_TRUTH_POSE))
        self.t = 0.0
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self.stop.wait(0.005):
            with self.lock:
                t = self.t
                self.t += STEP_S
                self.clock.publish(t)
                if t <= self.poses_until:
                    self.truth.put(topics.TruthPose(t=t, x=1.0, y=2.0, z=1.5, yaw=0.0).to_bytes())

    def inject_clock(self, t: float) -> None:
        """One odd sim/clock sample between two regular ones (schema-valid or not)."""
        with self.lock:
            self.raw_clock.put(json.dumps({"t": t, "speedup": 10.0}).encode())

    def restart(self) -> float:
        """The vehicle process restarts: its clock starts again at 0. Returns the time it had reached."""
        with self.lock:
            old, self.t = self.t, 0.0
        return old


class Histograms:
    def __init__(self):
        self.items: list[topics.Histogram] = []
        self.lock = threading.Lock()

    def __call__(self, sample) -> None:
        h = topics.Histogram.from_bytes(sample.payload.to_bytes())
        with self.lock:
            self.items.append(h)

    def wait(self, cond, what: str, start: int = 0) -> topics.Histogram:
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline:
            with self.lock:
                for h in self.items[start:]:
                    if cond(h):
                        return h
            time.sleep(0.02)
        with self.lock:
            tail = [(h.t, h.flags) for h in self.items[-5:]]
        raise AssertionError(f"no histogram {what}; last ones (t, flags): {tail}")

    def __len__(self) -> int:
        with self.lock:
            return len(self.items)


def saw(proc: Proc, text: str) -> None:
    """``proc`` has logged a line containing ``text`` (already or within WAIT_S)."""
    if not any(text in line for line in proc.seen):
        proc.wait_line(text, timeout=WAIT_S)


@pytest.mark.slow
def test_detector_survives_clock_jumps_and_an_owner_restart(router):
    hists = Histograms()
    with open_session(connect=router) as session:
        sub = session.declare_subscriber(topics.key(topics.HISTOGRAM), hists)
        owner = Owner(session)
        det = Proc("detector", "--connect", router, "--clock", "zenoh", "--seed", "1")
        try:
            det.wait_line("waiting for", timeout=WAIT_S)  # response built: start the clock as `radseek run` does
            owner.thread.start()
            det.wait_line("publishing", timeout=WAIT_S)
            hists.wait(lambda h: h.t >= 3.0 and not h.flags & topics.FLAG_STALE_POSE, "at t >= 3 s with a pose")

            # one schema-valid sample 1e6 s ahead, one out of range (1e9), then the clock goes on
            t_jump = hists.wait(lambda h: h.t >= 5.0, "at t >= 5 s").t
            owner.inject_clock(1e6)
            owner.inject_clock(1e9)
            later = hists.wait(lambda h: h.t >= t_jump + 5.0, "5 s of sim time after the jump (frozen?)")
            assert later.t < 1e3
            with hists.lock:
                assert max(h.t for h in hists.items) < 1e3, "a frame was stamped on the bogus timeline"
            saw(det, "dropped 1 sample(s) off the timeline")
            saw(det, "dropped invalid sample")

            # the vehicle restarts while the detector runs: its clock starts again near 0
            n0 = len(hists)
            t_old = owner.restart()
            assert t_old > 8.0
            saw(det, "went back")
            # frames come again on the new timeline, measured at true poses (not stale)
            h = hists.wait(lambda h: 2.0 <= h.t < t_old - 2.0 and not h.flags & topics.FLAG_STALE_POSE,
                           "on the restarted clock with a true pose", start=n0)
            assert h.t < t_old
        finally:
            owner.stop.set()
            owner.thread.join(10)
            det.stop()
            sub.undeclare()


def test_follower_drops_an_unconfirmed_jump_and_resyncs_on_a_confirmed_one(router):
    with open_session(connect=router) as session:
        clock = ZenohClock(session, "uav0", max_lead=0.05)
        try:
            for k in range(20):
                clock.offer(10.0 + 0.05 * k, 1.0)
            assert 10.9 < clock.now() < 11.0
            clock.offer(1e6, 1.0)  # one odd sample: held, not trusted
            assert clock.now() < 11.0 and clock.resyncs == 0
            clock.offer(10.0 + 0.05 * 20, 1.0)  # the old timeline goes on: the odd sample is dropped
            assert clock.rejected == 1 and clock.now() < 11.1
            clock.offer(9.5, 1.0)  # a late duplicate: ignored, not a jump
            assert clock.rejected == 1 and clock.now() >= 11.0
            # the owner restarts: three samples in a row near 0 confirm the new timeline
            for t in (0.0, 0.05, 0.1):
                clock.offer(t, 1.0)
            assert clock.resyncs == 1 and clock.epoch == 1 and clock.now() < 0.2
            assert clock.last_jump == (pytest.approx(11.0), pytest.approx(0.1))
        finally:
            clock.undeclare()


@pytest.mark.slow
def test_frames_made_without_their_true_pose_are_counted(router):
    """A lockstep detector (``--truth-wait``) waits for the true pose at each frame's end; when the truth stream
    stops after 2.0 s while the clock goes on to 4.0 s, the frames after it are made without it, and its stop line
    counts them (so a run whose frames may differ from an unhurried one's says so: tests/test_run_flood_summary.py).
    Before 2.0 s every pose came: at most the frames after 2.0 s are counted, and at least the first of them."""
    with open_session(connect=router) as session:
        owner = Owner(session, poses_until=2.025)  # between two steps
        det = Proc("detector", "--connect", router, "--clock", "zenoh", "--seed", "1", "--truth-wait", "2.0",
                   "--until", "4.0")
        try:
            det.wait_line("waiting for", timeout=WAIT_S)
            owner.thread.start()
            line = det.wait_line("stopped after", timeout=WAIT_S)
        finally:
            owner.stop.set()
            owner.thread.join(10)
            det.stop()
    hurried = int(re.search(r"(\d+) made without the true pose at their end", line).group(1))
    assert 1 <= hurried <= round((4.0 - 2.0) / 0.1), line
