"""The vehicle's side of lockstep (PX4 SITL style): sim time waits for the mission process.

The mission publishes ``mission/lockstep`` (``radseek.topics.MissionLockstep``) after it has handled
each histogram frame, after the MAVLink commands it sent in response. ``LockstepGate.limit()`` is the
sim time the vehicle may step to: ``until`` of the last message, 0 before the first one (the vehicle
holds at t = 0 until the mission attaches, so the same seed starts the same flight however slowly the
processes start). The vehicle keeps answering MAVLink while it holds.

Released (``limit()`` is None, the vehicle runs free on its own clock and its own failsafes apply):
when the mission says ``attached: false`` (it is done), or by the watchdog when no message came for
``timeout_s`` wall seconds (``startup_timeout_s`` before the first one): a killed mission never
freezes the vehicle. A release is logged (warning for the watchdog) and final.
"""

from __future__ import annotations

import logging
import socket
import threading
import time

from radseek import topics
from radseek.payload_drops import DropCounter

log = logging.getLogger(__name__)


class LockstepGate:
    def __init__(self, timeout_s: float = 5.0, startup_timeout_s: float = 60.0):
        self.timeout_s = timeout_s
        self.startup_timeout_s = max(startup_timeout_s, timeout_s)
        self._lock = threading.Lock()
        self._start = time.monotonic()
        self._until = 0.0
        self._t = 0.0
        self._busy = False
        self._last_msg: float | None = None
        self.released: str | None = None  # why lockstep was released (None while engaged)
        self.messages = 0
        self._drops = DropCounter(log, "lockstep: dropped invalid message")
        # wakes the vehicle loop's select() at once when a message arrives
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)

    # -- input -----------------------------------------------------------------------------------
    def on_sample(self, sample) -> None:
        msg = self._drops.decode(topics.MissionLockstep, sample)
        if msg is not None:
            self.offer(msg)

    def offer(self, msg: topics.MissionLockstep) -> None:
        with self._lock:
            self.messages += 1
            self._last_msg = time.monotonic()
            if self.released is None:
                if not msg.attached:
                    self.released = f"the mission left lockstep at t={msg.t:.2f} s"
                    log.info("lockstep released: %s", self.released)
                else:
                    self._until = max(self._until, msg.until)  # a late repeat never takes time back
                    self._t, self._busy = msg.t, msg.busy
        try:
            self._wake_w.send(b"\0")
        except OSError:  # buffer full: the loop is awake anyway
            pass

    @property
    def bad_messages(self) -> int:
        """Messages that failed validation (dropped)."""
        return self._drops.count

    # -- for the vehicle loop --------------------------------------------------------------------
    def limit(self, now_wall: float | None = None) -> float | None:
        """Sim time the vehicle may step to, or None once released (watchdog checked here)."""
        now = time.monotonic() if now_wall is None else now_wall
        with self._lock:
            if self.released is not None:
                return None
            if self._last_msg is None:
                if now - self._start > self.startup_timeout_s:
                    self.released = f"no mission/lockstep message in {self.startup_timeout_s:g} s wall"
            elif now - self._last_msg > self.timeout_s:
                self.released = f"no mission/lockstep message for {self.timeout_s:g} s wall (mission gone?), " \
                                f"last at t={self._t:.2f} s"
            if self.released is not None:
                log.warning("lockstep released: %s: the vehicle runs free, its own failsafes apply", self.released)
                return None
            return self._until

    @property
    def busy(self) -> bool:
        with self._lock:
            return self._busy

    @property
    def wake_socket(self) -> socket.socket:
        return self._wake_r

    def drain_wake(self) -> None:
        try:
            while self._wake_r.recv(4096):
                pass
        except (BlockingIOError, InterruptedError, OSError):
            pass

    def close(self) -> None:
        for s in (self._wake_r, self._wake_w):
            try:
                s.close()
            except OSError:
                pass
