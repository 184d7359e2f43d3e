"""One recorded frame: a detector histogram joined with the estimated pose and the dwell index.

``FrameRecord`` is the only place the order of a ``frames.csv`` row lives (``COLUMNS``,
shared/spec/dataset-format.md): the flight recorder, the in-process driver, the dataset writer and the
estimators' columnar ``radseek.dataset.Frames`` all go through it instead of writing
``[t, duration, x, ...]`` by hand. Its counts live in a ``Spectrum`` together with their channel edges
and live time (like becquerel's ``Spectrum``), in one declared integer type, ``COUNT_DTYPE``, from the
histogram's JSON list to the columns the estimators fit.

Which frames are usable is a function of the histogram's flags, defined here once:

* ``usable(flags)``: the frame measures the field at its pose. Stale-pose frames (the emulator had no
  true pose and sent zeros) and CRC-damaged ones do not: they go to ``frames_flagged.csv``, never to an
  estimator. A frame without a pose estimate is not usable either (``FrameRecord.usable``).
* ``usable_rate(flags)``: a usable frame whose count rate is unbiased. A saturated frame lost counts: it
  still reaches the estimators (its pose and the remaining counts are real) but it does not run the
  dwell clock, whose mean rate it would pull down.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from radseek import topics
from radseek.pose_history import PoseHistory
from radseek.spectrum import Spectrum
from radseek.topics import N_CHANNELS

#: the one integer type of a frame's counts, from the histogram to ``Frames.counts``
COUNT_DTYPE = np.dtype(np.int64)

#: the columns of frames.csv, in order (shared/spec/dataset-format.md)
POSE_COLUMNS = ["t", "duration", "x", "y", "z", "yaw", "var_x", "var_y", "var_z", "dwell"]
CHANNEL_COLUMNS = [f"c{k:02d}" for k in range(N_CHANNELS)]
COLUMNS = POSE_COLUMNS + CHANNEL_COLUMNS


def _csv_cell(value: Any, column: str) -> str:
    """A pose cell as frames.csv writes it: ``dwell`` an integer, the others the shortest text that reads back
    as the same float. Rounded cells (4 decimals, as before 2026-11-26) moved a walled fit's basin: lattice-wall
    seed 0's dwell-4 estimate replayed from frames.csv 0.22 m from the flown one, which its MCAP log reproduces."""
    return str(int(value)) if column == "dwell" else repr(float(value))


#: flags of a frame that is no measurement of the field at any pose
NOT_A_MEASUREMENT = topics.FLAG_STALE_POSE | topics.FLAG_CRC_ERROR


def usable(flags: int) -> bool:
    """A frame with these histogram flags measures the field: recorded in frames.csv, fitted by estimators."""
    return not flags & NOT_A_MEASUREMENT


def usable_rate(flags: int) -> bool:
    """A usable frame whose count rate is unbiased (not saturated): only these run the dwell clock."""
    return usable(flags) and not flags & topics.FLAG_SATURATED


#: s of estimated poses a recorder keeps to join frames with (the mission's and an MCAP replay's history)
POSE_KEEP_S = 120.0


def pose_for(hist: topics.Histogram, poses: PoseHistory) -> topics.Pose | None:
    """The one pose-join rule: a frame's estimated pose is the pose interpolated at its mid-time
    (``t - duration / 2``) from the estimated poses received (None: none near it). The mission's recorder, the
    in-process driver and the MCAP replay all join frames with it."""
    return poses.at(hist.t - hist.duration / 2)


def as_counts(counts: Any) -> np.ndarray:
    """Counts of one frame as a ``(N_CHANNELS,)`` array of ``COUNT_DTYPE``; ValueError if not whole numbers."""
    arr = np.asarray(counts)
    if arr.shape != (N_CHANNELS,):
        raise ValueError(f"counts must have {N_CHANNELS} channels, got shape {arr.shape}")
    out = arr.astype(COUNT_DTYPE)
    if not np.array_equal(out, arr):
        raise ValueError("counts must be whole numbers")
    return out


@dataclass(frozen=True)
class FrameRecord:
    """One row of frames.csv: the histogram's spectrum at the estimated pose, in a dwell (or -1 moving).

    ``seq`` and ``flags`` are the board's; frames.csv carries them as added columns. ``vehicle`` is the team
    index of the vehicle that recorded it (0 alone; each team vehicle writes its own folder).
    """

    t: float  # s, sim time at the frame's end
    spectrum: Spectrum
    x: float  # m, ENU, estimated pose at the frame's mid time
    y: float
    z: float
    yaw: float  # rad
    var_x: float  # m^2
    var_y: float
    var_z: float
    dwell: int  # dwell index, -1 while moving
    seq: int = 0
    flags: int = 0
    vehicle: int = 0

    def __post_init__(self) -> None:
        c = self.spectrum.counts  # a frame holds the board's N_CHANNELS whole counts, as COUNT_DTYPE
        if c.dtype != COUNT_DTYPE or c.shape != (N_CHANNELS,):
            object.__setattr__(self, "spectrum", dataclasses.replace(self.spectrum, counts=as_counts(c)))

    @classmethod
    def from_histogram(cls, hist: topics.Histogram, pose: topics.Pose | None, dwell: int,
                       channel_edges_keV: np.ndarray | None = None) -> FrameRecord:
        """The record of a histogram at an estimated pose (None: no estimate, the pose is NaN)."""
        p = pose or topics.Pose(t=hist.t, x=math.nan, y=math.nan, z=math.nan, yaw=math.nan)
        spectrum = Spectrum(as_counts(hist.counts), livetime=hist.live_time, realtime=hist.duration,
                            bin_edges_kev=channel_edges_keV)
        return cls(hist.t, spectrum, p.x, p.y, p.z, p.yaw, p.var_x, p.var_y, p.var_z, int(dwell), hist.seq, hist.flags)

    @property
    def duration(self) -> float:
        return self.spectrum.realtime

    @property
    def counts(self) -> np.ndarray:
        return self.spectrum.counts

    @property
    def has_pose(self) -> bool:
        return all(math.isfinite(v) for v in (self.x, self.y, self.z, self.yaw))

    @property
    def usable(self) -> bool:
        """A measurement of the field at a known pose (see ``usable``)."""
        return self.has_pose and usable(self.flags)

    def values(self) -> list[float | int]:
        """The row in ``COLUMNS`` order: pose columns, then the counts as integers."""
        return [*(getattr(self, c) for c in POSE_COLUMNS), *(int(c) for c in self.counts)]

    def csv_cells(self) -> list[str]:
        """The row as frames.csv writes it, in ``COLUMNS`` order."""
        return [_csv_cell(getattr(self, c), c) for c in POSE_COLUMNS] + [str(int(c)) for c in self.counts]
