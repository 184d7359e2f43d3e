"""Flight recording: every received histogram joined with the vehicle's *estimated* pose, written to a
dataset as it arrives (radseek-dataset/1), so a crash loses nothing already received.

The join takes the pose at the middle of the frame's integration interval (``t - duration/2``),
interpolated linearly between the estimated poses received from the vehicle (yaw unwrapped).

A recorder never opens a folder that already holds ``frames.csv`` or ``frames_flagged.csv``
(``FileExistsError``): a flight is never truncated by the next one.

Frames that carry no usable measurement (``radseek.frame_record.usable``: flagged stale-pose, the
emulator had no true pose and published zero counts, or CRC-damaged, or received with no pose estimate)
are not measurements of the field at any pose, so writing them to ``frames.csv`` would make every reader
see false zero-count frames. They go, with their flags, to ``frames_flagged.csv`` beside it (same
columns plus ``flags`` and ``seq``); ``frames.csv`` also gains a ``seq`` and a ``flags`` column (readers
ignore unknown columns). So every received frame is in the dataset, and
``received == rows(frames.csv) + rows(frames_flagged.csv)`` always holds.

A usable frame that does not end after the last one in ``frames.csv`` goes to ``frames_flagged.csv`` too (counted
in ``out_of_order``): the dataset contract keeps ``frames.csv`` in time order, and one such row made a whole flight
unreadable. Seen under a CPU hog with a board flooding 100x: the router dropped a real histogram, and a forged copy
with its sequence number (and t = 1.0) came in its place; the run ended "no report".
"""

from __future__ import annotations

from pathlib import Path

from radseek import topics
from radseek.dataset import Scenario
from radseek.frame_record import FrameRecord
from radseek.pose_history import PoseHistory
from radseek_io.dataset import FrameWriter, write_json

__all__ = ["FlightRecorder", "PoseHistory", "flagged_rows"]


class FlightRecorder:
    """Writes a dataset directory while flying: scenario.json first, then one row per received frame."""

    def __init__(self, path: str | Path, scenario: Scenario):
        self.path = Path(path)
        self.path.mkdir(parents=True, exist_ok=True)
        for name in ("frames.csv", "frames_flagged.csv"):  # never truncate a recorded flight
            if (self.path / name).exists():
                raise FileExistsError(f"{self.path / name} already holds a recorded flight: record elsewhere "
                                      "(or remove it first, e.g. radseek mission --force)")
        write_json(self.path / "scenario.json", scenario.to_dict())
        self.channel_edges_keV = scenario.channel_edges_keV
        self._frames = FrameWriter(self.path, extra_columns=("seq", "flags"))
        self._flagged = FrameWriter(self.path, extra_columns=("flags", "seq"), filename="frames_flagged.csv")
        self.received = 0
        self.flagged = 0
        self.no_pose = 0
        self.out_of_order = 0  # usable frames not after the last one recorded (to frames_flagged.csv)
        self._last_t = float("-inf")

    @property
    def recorded(self) -> int:
        return self._frames.rows

    def record(self, hist: topics.Histogram, pose: topics.Pose | None, dwell: int) -> bool:
        """Record one frame; True if it went to frames.csv (usable), False if to frames_flagged.csv."""
        return self.write(FrameRecord.from_histogram(hist, pose, dwell, self.channel_edges_keV))

    def write(self, record: FrameRecord) -> bool:
        """Write one frame record; True if it went to frames.csv (usable), False if to frames_flagged.csv."""
        self.received += 1
        if record.usable and record.t > self._last_t:
            self._last_t = record.t
            self._frames.write(record)
            return True
        self.flagged += 1
        self.no_pose += not record.has_pose
        self.out_of_order += record.usable
        self._flagged.write(record)
        return False

    def close(self) -> None:
        self._frames.close()
        self._flagged.close()

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
