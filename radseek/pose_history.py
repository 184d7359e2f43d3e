"""Poses by simulation time, interpolated: the one way radseek asks "where was the vehicle at t?".

Used on both sides of the truth boundary: the detector emulator interpolates ``sim/truth_pose`` at a
frame's mid-time (the counts it draws belong to the interval, not to whichever pose arrived last), and
the recorder interpolates the *estimated* ``pose`` at the same mid-time to annotate the frame. Works for
any frozen dataclass payload with ``t, x, y, z, yaw`` (``topics.TruthPose``, ``topics.Pose``); other
float fields named ``var_*`` are interpolated linearly too.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
import threading
from typing import Generic, TypeVar

P = TypeVar("P")


class PoseHistory(Generic[P]):
    """A bounded, thread-safe window of poses in time order; linear interpolation, yaw unwrapped.

    One pose off the timeline (a forged or corrupt time far ahead, a stale one far behind) must not
    capture the history: a pose more than ``max_jump_s`` from the latest is held aside and taken only
    when the next pose confirms its timeline (a real gap in the stream, or the owner restarted and its
    clock went back, which starts the history anew). A single outlier is dropped and costs nothing."""

    def __init__(self, keep_s: float = 60.0, max_jump_s: float = 5.0):
        self.keep_s = keep_s
        self.max_jump_s = max_jump_s
        self._t: list[float] = []
        self._p: list[P] = []
        self._held: P | None = None  # a pose off the timeline, waiting for a second one to confirm it
        self.dropped_jumps = 0  # poses off the timeline that no second pose confirmed
        self.restarts = 0  # confirmed jumps back in time: the history started anew
        self._lock = threading.Lock()

    def add(self, pose: P) -> bool:
        """Add ``pose``; False when it is not (yet) taken: out of order, or off the timeline."""
        t = pose.t  # type: ignore[attr-defined]
        with self._lock:
            if self._t and abs(t - self._t[-1]) > self.max_jump_s:
                held, self._held = self._held, pose
                if held is None or not 0.0 <= t - held.t <= self.max_jump_s:  # type: ignore[attr-defined]
                    if held is not None:
                        self.dropped_jumps += 1
                    return False
                self._held = None
                if t < self._t[-1]:  # the timeline went back and two poses agree: start anew
                    self.restarts += 1
                    self._t, self._p = [], []
                self._append(held)
                self._append(pose)
                return True
            if self._held is not None:
                self.dropped_jumps += 1
                self._held = None
            if self._t and t < self._t[-1]:
                return False  # out of order: the newer estimate wins
            self._append(pose)
            return True

    def _append(self, pose: P) -> None:
        t = pose.t  # type: ignore[attr-defined]
        self._t.append(t)
        self._p.append(pose)
        cut = bisect.bisect_left(self._t, t - self.keep_s)
        if cut:
            del self._t[:cut], self._p[:cut]

    def __len__(self) -> int:
        return len(self._t)

    def latest(self) -> P | None:
        with self._lock:
            return self._p[-1] if self._p else None

    def at(self, t: float, max_gap_s: float = 1.0) -> P | None:
        """The pose at ``t``, or None when no pose lies within ``max_gap_s`` of it."""
        with self._lock:
            if not self._t:
                return None
            i = bisect.bisect_left(self._t, t)
            if i < len(self._t) and self._t[i] == t:
                return self._p[i]
            if i == 0 or i == len(self._t):
                j = 0 if i == 0 else len(self._t) - 1
                return self._p[j] if abs(self._t[j] - t) <= max_gap_s else None
            a, b = self._p[i - 1], self._p[i]
            ta, tb = self._t[i - 1], self._t[i]
        if tb - ta > 2 * max_gap_s:
            return None
        w = (t - ta) / (tb - ta)
        changes: dict[str, float] = {"t": t}
        for f in dataclasses.fields(a):  # type: ignore[arg-type]
            if f.name in ("x", "y", "z") or f.name.startswith("var_"):
                u, v = getattr(a, f.name), getattr(b, f.name)
                changes[f.name] = u + w * (v - u)
        dyaw = math.remainder(b.yaw - a.yaw, 2 * math.pi)  # type: ignore[attr-defined]
        changes["yaw"] = math.remainder(a.yaw + w * dyaw, 2 * math.pi)  # type: ignore[attr-defined]
        return dataclasses.replace(a, **changes)  # type: ignore[type-var]
