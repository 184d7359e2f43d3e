"""The one simulation clock (ArduPilot SITL style): every process reads sim time, never the wall clock.

Two implementations of one small interface (``now()``, ``sleep_until(t)``, ``speedup``):

- ``FreeRunningClock``: sim time = speedup x wall time since start. A process that owns time (the
  vehicle, or a detector run on its own) uses it and publishes ``sim/clock`` with ``ClockPublisher``.
- ``ZenohClock``: follows ``sim/clock`` messages from the owner. ``now()`` is the last published time
  plus the wall time since, scaled by the published speed-up, but never more than ``max_lead`` sim
  seconds past the last message, so a stalled owner stalls its followers instead of letting them run
  ahead.
"""

from __future__ import annotations

import threading
import time
from typing import Protocol

import zenoh

from radseek import topics


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
        self._pub = session.declare_publisher(topics.key(topics.SIM_CLOCK, vehicle))

    def publish(self, t: float) -> None:
        self._pub.put(topics.SimClock(t=float(t), speedup=self.speedup).to_bytes())

    def undeclare(self) -> None:
        self._pub.undeclare()


class ZenohClock:
    """Follows the owner's ``sim/clock`` messages."""

    def __init__(self, session: zenoh.Session, vehicle: str, max_lead: float = 0.05):
        self.speedup = 1.0
        self.max_lead = max_lead
        self._t = -1.0
        self._wall = time.monotonic()
        self._cond = threading.Condition()
        self._sub = session.declare_subscriber(topics.key(topics.SIM_CLOCK, vehicle), self._on_clock)

    def _on_clock(self, sample: zenoh.Sample) -> None:
        try:
            msg = topics.SimClock.from_bytes(sample.payload.to_bytes())
        except topics.PayloadError:
            return
        with self._cond:
            if msg.t >= self._t:
                self._t, self.speedup, self._wall = msg.t, msg.speedup, time.monotonic()
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
