"""Flight recording: every received histogram joined with the vehicle's *estimated* pose, written to a
dataset as it arrives (radseek-dataset/1), so a crash loses nothing already received.

The join takes the pose at the middle of the frame's integration interval (``t - duration/2``),
interpolated linearly between the estimated poses received from the vehicle (yaw unwrapped).

Frames that carry no usable measurement — flagged stale-pose (the emulator had no true pose and
published zero counts) or CRC-damaged — are not measurements of the field at any pose, so writing
them to ``frames.csv`` would make every reader see false zero-count frames. They go, with their flags,
to ``frames_flagged.csv`` beside it (same columns plus ``flags``); ``frames.csv`` also gains a
``flags`` and a ``seq`` column (readers ignore unknown columns). So every received frame is in the
dataset, and
``received == rows(frames.csv) + rows(frames_flagged.csv)`` always holds.
"""

from __future__ import annotations

import bisect
import csv
import math
from pathlib import Path

from radseek import topics
from radseek.dataset import COLUMNS, FrameWriter, Scenario, write_json

UNUSABLE = topics.FLAG_STALE_POSE | topics.FLAG_CRC_ERROR


class PoseHistory:
    """Estimated poses by sim time; linear interpolation, yaw unwrapped. Keeps a bounded window."""

    def __init__(self, keep_s: float = 60.0):
        self.keep_s = keep_s
        self._t: list[float] = []
        self._p: list[topics.Pose] = []

    def add(self, pose: topics.Pose) -> None:
        if self._t and pose.t < self._t[-1]:
            return  # out of order: the newer estimate wins
        self._t.append(pose.t)
        self._p.append(pose)
        cut = bisect.bisect_left(self._t, pose.t - self.keep_s)
        if cut:
            del self._t[:cut], self._p[:cut]

    def __len__(self) -> int:
        return len(self._t)

    def at(self, t: float, max_gap_s: float = 1.0) -> topics.Pose | None:
        """The pose at ``t``, or None when no estimate lies within ``max_gap_s`` of it."""
        if not self._t:
            return None
        i = bisect.bisect_left(self._t, t)
        if i < len(self._t) and self._t[i] == t:
            return self._p[i]
        if i == 0 or i == len(self._t):
            j = 0 if i == 0 else len(self._t) - 1
            return self._p[j] if abs(self._t[j] - t) <= max_gap_s else None
        a, b = self._p[i - 1], self._p[i]
        if b.t - a.t > 2 * max_gap_s:
            return None
        w = (t - a.t) / (b.t - a.t)
        dyaw = math.remainder(b.yaw - a.yaw, 2 * math.pi)

        def lerp(u: float, v: float) -> float:
            return u + w * (v - u)

        return topics.Pose(
            t=t, x=lerp(a.x, b.x), y=lerp(a.y, b.y), z=lerp(a.z, b.z),
            yaw=math.remainder(a.yaw + w * dyaw, 2 * math.pi),
            var_x=lerp(a.var_x, b.var_x), var_y=lerp(a.var_y, b.var_y), var_z=lerp(a.var_z, b.var_z),
            var_yaw=lerp(a.var_yaw, b.var_yaw),
        )


class FlightRecorder:
    """Writes a dataset directory while flying: scenario.json first, then one row per received frame."""

    def __init__(self, path: str | Path, scenario: Scenario):
        self.path = Path(path)
        self.path.mkdir(parents=True, exist_ok=True)
        write_json(self.path / "scenario.json", scenario.to_dict())
        self._frames = FrameWriter(self.path, extra_columns=("seq", "flags"))
        self._flagged_fh = open(self.path / "frames_flagged.csv", "w", newline="")  # noqa: SIM115
        self._flagged = csv.writer(self._flagged_fh)
        self._flagged.writerow([*COLUMNS, "flags", "seq"])
        self.received = 0
        self.flagged = 0
        self.no_pose = 0

    @property
    def recorded(self) -> int:
        return self._frames.rows

    def record(self, hist: topics.Histogram, pose: topics.Pose | None, dwell: int) -> bool:
        """Record one frame; True if it went to frames.csv (usable), False if to frames_flagged.csv."""
        self.received += 1
        usable = pose is not None and not (hist.flags & UNUSABLE)
        if usable:
            assert pose is not None
            self._frames.write_frame(
                hist.t, hist.duration, (pose.x, pose.y, pose.z), pose.yaw, (pose.var_x, pose.var_y, pose.var_z),
                dwell, hist.counts, extra=(hist.seq, hist.flags),
            )
            return True
        self.flagged += 1
        self.no_pose += pose is None
        p = pose or topics.Pose(t=hist.t, x=math.nan, y=math.nan, z=math.nan, yaw=math.nan)
        row = [hist.t, hist.duration, p.x, p.y, p.z, p.yaw, p.var_x, p.var_y, p.var_z, dwell, *hist.counts]
        self._flagged.writerow([*(f"{v:.6g}" if isinstance(v, float) else v for v in row), hist.flags, hist.seq])
        self._flagged_fh.flush()
        return False

    def close(self) -> None:
        self._frames.close()
        if not self._flagged_fh.closed:
            self._flagged_fh.close()

    def __enter__(self) -> FlightRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def flagged_rows(path: str | Path) -> int:
    """Number of rows in a dataset's frames_flagged.csv (0 when absent)."""
    f = Path(path) / "frames_flagged.csv"
    if not f.exists():
        return 0
    with open(f) as fh:
        return max(sum(1 for _ in fh) - 1, 0)
