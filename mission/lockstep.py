"""The mission's side of lockstep: ``mission/lockstep`` (``radseek.topics.MissionLockstep``).

The mission takes the histogram frames one at a time (``take``), sends whatever MAVLink commands a
frame calls for, and only then acks it (``ack``): a vehicle run with ``--lockstep`` steps sim time to
``until`` = the frame's time plus one frame and no further, so the next frame exists only once this
one is fully handled, and a command is applied at the sim time of the frame it answers. While the
mission computes, a background thread repeats the last state (``busy``) twice a wall second: the
vehicle's watchdog then knows the mission is alive. ``detach`` leaves lockstep (the vehicle runs free).
"""

from __future__ import annotations

import threading

import zenoh

from radseek import topics

HEARTBEAT_WALL_S = 0.5


class LockstepAck:
    def __init__(self, session: zenoh.Session, vehicle: str, heartbeat_wall_s: float = HEARTBEAT_WALL_S):
        self._pub = topics.declare_publisher(session, topics.MISSION_LOCKSTEP, vehicle)
        self._lock = threading.Lock()
        # attached, nothing taken yet: the vehicle holds at t = 0 until the first ack
        self._msg = topics.MissionLockstep(t=0.0, until=0.0, busy=True)
        self._stop = threading.Event()
        self.acks = 0
        self._put()
        self._thread = threading.Thread(target=self._heartbeat, args=(heartbeat_wall_s,), name="lockstep",
                                        daemon=True)
        self._thread.start()

    def _put(self) -> None:
        with self._lock:
            if not self._stop.is_set() or not self._msg.attached:
                try:
                    self._pub.put(self._msg.to_bytes())
                except Exception:  # noqa: BLE001 - a closed session at shutdown
                    pass

    def _heartbeat(self, period: float) -> None:
        while not self._stop.wait(period):
            self._put()

    def take(self, t: float) -> None:
        """The mission works on the frame ending at ``t`` (busy: the vehicle holds at ``t``)."""
        with self._lock:
            self._msg = topics.MissionLockstep(t=t, until=t, busy=True)

    def ack(self, t: float, frame_s: float) -> None:
        """Everything up to ``t`` is handled (commands already sent): the vehicle may step one frame on."""
        with self._lock:
            self._msg = topics.MissionLockstep(t=t, until=t + frame_s, busy=False)
            self.acks += 1
        self._put()

    def detach(self) -> None:
        """Leave lockstep: the vehicle runs free from here (the mission has landed or is stopping)."""
        if self._stop.is_set():
            return
        with self._lock:
            m = self._msg
            self._msg = topics.MissionLockstep(t=m.t, until=m.until, busy=False, attached=False)
            self._stop.set()
        self._put()
        self._thread.join(timeout=2.0)
        try:
            self._pub.undeclare()
        except Exception:  # noqa: BLE001
            pass
