"""The one simulation clock (ArduPilot SITL style): every process reads sim time, never the wall clock.

Two implementations of one small interface (``now()``, ``sleep_until(t)``, ``speedup``):

- ``FreeRunningClock``: sim time = speedup x wall time since start. A process that owns time (the
  vehicle, or a detector run on its own) uses it and publishes ``sim/clock`` with ``ClockPublisher``.
- ``ZenohClock``: follows ``sim/clock`` messages from the owner. ``now()`` is the last published time
  plus the wall time since, scaled by the published speed-up, but never more than ``max_lead`` sim
  seconds past the last message, so a stalled owner stalls its followers instead of letting them run
  ahead.

A follower does not trust a sample blindly: one that jumps back (more than ``max_back_s``) or far
ahead (more than ``max_jump_s`` past where the clock should be by now) is held as the start of a
candidate new timeline. If the owner's next samples continue that timeline (``confirm`` samples in a
row: the owner restarted near 0, or really jumped), the follower resynchronises to it and counts a
``resync``; if the old timeline goes on instead, the odd samples are dropped and counted as
``rejected``. Either way it is reported (``logging``, logger ``radseek.simclock``) and followers can
watch ``epoch`` (incremented at every resync) to re-derive anything they computed from the old time.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Protocol

import zenoh

from radseek import topics
from radseek.payload_drops import DropCounter

log = logging.getLogger(__name__)

class Clock(Protocol):
    speedup: float

    def now(self) -> float: ...

    def sleep_until(self, t: float, timeout_wall_s: float | None = None) -> bool: ...


class FreeRunningClock:
    """Sim time advancing ``speedup`` times faster than the wall clock, from ``t0``."""

    def __init__(self, speedup: float = 1.0, t0: float = 0.0):
        if speedup <= 0:
            raise ValueError(f"speedup must be > 0, got {speedup}")
        self.speedup = float(speedup)
        self._t0 = float(t0)
        self._wall0 = time.monotonic()

    def now(self) -> float:
        return self._t0 + (time.monotonic() - self._wall0) * self.speedup

    def sleep_until(self, t: float, timeout_wall_s: float | None = None) -> bool:
        wait = (t - self.now()) / self.speedup
        if timeout_wall_s is not None and wait > timeout_wall_s:
            time.sleep(max(timeout_wall_s, 0.0))
            return False
        if wait > 0:
            time.sleep(wait)
        return True


class ClockPublisher:
    """Publishes ``sim/clock`` for the clock owner; call ``publish(t)`` at every step (or use ``run``)."""

    def __init__(self, session: zenoh.Session, vehicle: str, speedup: float):
        self.speedup = speedup
        self._pub = topics.declare_publisher(session, topics.SIM_CLOCK, vehicle)

    def publish(self, t: float) -> None:
        self._pub.put(topics.SimClock(t=float(t), speedup=self.speedup).to_bytes())

    def undeclare(self) -> None:
        self._pub.undeclare()


class ZenohClock:
    """Follows the owner's ``sim/clock`` messages (see the module doc for jumps and resynchronisation)."""

    def __init__(self, session: zenoh.Session, vehicle: str, max_lead: float = 0.05, *,
                 max_jump_s: float = 10.0, max_back_s: float = 1.0, confirm: int = 3):
        self.speedup = 1.0
        self.max_lead = max_lead
        self.max_jump_s = max_jump_s  # sim s past the expected time: further is a jump, not trusted at once
        self.max_back_s = max_back_s  # sim s behind the last time: less is a late duplicate, ignored
        self.confirm = max(1, int(confirm))
        self._t = -1.0
        self._wall = time.monotonic()
        self._cond = threading.Condition()
        # the candidate new timeline: (last t, its wall time, samples seen in a row)
        self._cand: tuple[float, float, int] | None = None
        self.epoch = 0  # incremented at every resynchronisation
        self.resyncs = 0  # the clock was resynchronised to a new timeline (owner restart, real jump)
        self.rejected = 0  # samples off the timeline that the owner did not confirm (dropped)
        self._drops = DropCounter(log, "dropped invalid sample")  # samples that failed validation
        self.last_jump: tuple[float, float] | None = None  # (from, to) of the last resync
        self._sub = session.declare_subscriber(topics.key(topics.SIM_CLOCK, vehicle), self._on_clock)

    @property
    def bad_msgs(self) -> int:
        """Samples that failed validation (dropped)."""
        return self._drops.count

    def _on_clock(self, sample: zenoh.Sample) -> None:
        msg = self._drops.decode(topics.SimClock, sample)
        if msg is not None:
            self.offer(msg.t, msg.speedup)

    def offer(self, t: float, speedup: float) -> None:
        """One owner sample (sim time ``t``, its speed-up): accept, ignore, hold or resynchronise."""
        wall = time.monotonic()
        report = None
        with self._cond:
            if self._t < 0:
                self._accept(t, speedup, wall)
                return
            expected = self._t + (wall - self._wall) * self.speedup
            if self._t <= t <= expected + self.max_jump_s:  # the timeline goes on
                if self._cand is not None:
                    self.rejected += self._cand[2]
                    report = f"sim/clock: dropped {self._cand[2]} sample(s) off the timeline (t={self._cand[0]:.3f} s "\
                             f"while the clock is at {self._t:.3f} s)"
                    self._cand = None
                self._accept(t, speedup, wall)
            elif self._t - self.max_back_s <= t < self._t:
                return  # a late duplicate: the newer time wins
            else:
                c = self._cand
                if c is not None and c[0] - self.max_back_s <= t <= c[0] + (wall - c[1]) * speedup + self.max_jump_s:
                    c = (max(t, c[0]), wall, c[2] + 1)
                else:
                    if c is not None:
                        self.rejected += c[2]
                    c = (t, wall, 1)
                self._cand = c
                if c[2] >= self.confirm:
                    old = self._t
                    self._cand = None
                    self.resyncs += 1
                    self.epoch += 1
                    self.last_jump = (old, c[0])
                    self._t = -1.0  # accept the new timeline even if it is behind
                    self._accept(c[0], speedup, wall)
                    report = f"sim/clock: jumped from t={old:.3f} s to t={c[0]:.3f} s (confirmed by " \
                             f"{self.confirm} samples): resynchronised"
        if report:
            log.warning(report)

    def _accept(self, t: float, speedup: float, wall: float) -> None:
        self._t, self.speedup, self._wall = t, speedup, wall
        self._cond.notify_all()

    @property
    def started(self) -> bool:
        return self._t >= 0

    def wait_started(self, timeout_wall_s: float) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: self._t >= 0, timeout=timeout_wall_s)

    def now(self) -> float:
        with self._cond:
            if self._t < 0:
                return 0.0
            lead = (time.monotonic() - self._wall) * self.speedup
            return self._t + min(lead, self.max_lead)

    def sleep_until(self, t: float, timeout_wall_s: float | None = None) -> bool:
        """Block until sim time reaches ``t``; False if ``timeout_wall_s`` passed first."""
        deadline = None if timeout_wall_s is None else time.monotonic() + timeout_wall_s
        while True:
            now = self.now()
            if now >= t:
                return True
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                return False
            step = (t - now) / max(self.speedup, 1e-6)
            with self._cond:
                self._cond.wait(timeout=min(step, 0.05) if remaining is None else min(step, 0.05, remaining))

    def undeclare(self) -> None:
        self._sub.undeclare()
