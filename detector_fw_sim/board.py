"""Firmware emulation of the spectroscopy board: 10 Hz framing, sequence, board clock, status flags.

The MCU of paper 003 (sec. III-A) reads 32 comparator counters and reports them at 10 Hz. Here frame
``k`` integrates the interval ``[k T, (k+1) T)`` of board time (``T`` = 100 ms), carries ``seq = k``
and ``board_time_us`` = the end of the interval. The emulated board is powered on at sim time 0 and
its clock is the sim clock, so a restarted emulator process continues the sequence where board time
says it is, and a consumer sees the frames it missed as a sequence jump (``FLAG_GAP``).

A channel that counted more than its u16 field holds (65535 per frame, 655 kcps) is clamped to 65535
and the frame is flagged ``STATUS_SATURATED``: a clamped count is a lower bound, never a wrapped lie.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from radseek.board_wire import (
    COUNT_MAX,
    N_CHANNELS,
    STATUS_SATURATED,
    STATUS_STALE_POSE,
    U32_MAX,
    Frame,
)

FRAME_PERIOD_S = 0.1  # paper 003, sec. III-A: "reported by the microcontroller at 10Hz"


def clamp_counts(counts: np.ndarray) -> tuple[np.ndarray, bool]:
    """Counts clamped to the u16 channel field, and whether any channel saturated."""
    counts = np.asarray(counts)
    if counts.shape != (N_CHANNELS,):
        raise ValueError(f"expected {N_CHANNELS} channel counts, got shape {counts.shape}")
    if np.any(counts < 0):
        raise ValueError("channel counts must be >= 0")
    saturated = bool(np.any(counts > COUNT_MAX))
    return np.minimum(counts, COUNT_MAX).astype(np.int64), saturated


@dataclass(frozen=True)
class Board:
    """The board's framing rules; ``period_s`` is the report period (100 ms)."""

    period_s: float = FRAME_PERIOD_S

    def __post_init__(self) -> None:
        if not (self.period_s > 0 and math.isfinite(self.period_s)):
            raise ValueError(f"frame period must be > 0 s, got {self.period_s}")

    def index_at(self, t: float) -> int:
        """Index of the frame whose interval contains board time ``t`` (s)."""
        # the small tolerance keeps k*T computed in floating point inside interval k
        return max(0, math.floor(t / self.period_s + 1e-9))

    def interval(self, k: int) -> tuple[float, float]:
        """Start and end board time (s) of frame ``k`` (rounded to the ns: 0.3, not 0.30000000000000004)."""
        return round(k * self.period_s, 9), round((k + 1) * self.period_s, 9)

    def make_frame(self, k: int, counts: np.ndarray, *, stale_pose: bool = False) -> Frame:
        """Frame ``k`` reporting ``counts`` (32 non-negative integers) for its interval."""
        if k < 0:
            raise ValueError(f"frame index must be >= 0, got {k}")
        clamped, saturated = clamp_counts(counts)
        flags = (STATUS_SATURATED if saturated else 0) | (STATUS_STALE_POSE if stale_pose else 0)
        return Frame(
            seq=k & U32_MAX,  # the u32 counter wraps after 13.6 years at 10 Hz
            board_time_us=round((k + 1) * self.period_s * 1e6),
            integration_us=round(self.period_s * 1e6),
            flags=flags,
            counts=tuple(int(c) for c in clamped),
        )
