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

import csv
import math
from pathlib import Path

from radseek import topics
from radseek.dataset import COLUMNS, FrameWriter, Scenario, write_json
from radseek.pose_history import PoseHistory

UNUSABLE = topics.FLAG_STALE_POSE | topics.FLAG_CRC_ERROR

__all__ = ["FlightRecorder", "PoseHistory", "flagged_rows"]


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
