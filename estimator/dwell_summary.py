"""Per-dwell summaries of a flight: mean count rate with its Poisson error, mean pose, pose variance.

Paper 003 (sec. IV-A) and paper 001 (Algorithm 2) work on one averaged reading per dwell point
(lambda_k with sigma_lambda_k); the particle filters of papers 000/004 take measurements at ~1 Hz.
This module turns 10 Hz frames into those measurements:

- :func:`summarize_dwells` -> :class:`DwellSummary` (one row per dwell index >= 0, frames of a dwell pooled);
- :func:`chunk_frames` -> index arrays of consecutive frames grouped into measurements of at most
  ``seconds`` (never mixing two dwells, or a dwell with transit);
- :func:`summarize_chunks` -> a :class:`DwellSummary` over such chunks (transit included).

Pooling is exact for the rate (sum of counts / sum of durations); poses are the mean recorded pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radseek.dataset import Frames

__all__ = ["DwellSummary", "summarize_dwells", "chunk_frames", "summarize_chunks", "concat_frames"]


@dataclass(frozen=True)
class DwellSummary:
    """One row per measurement (dwell or chunk). Rates in counts per second (all channels)."""

    index: np.ndarray  # (K,) dwell index (or -1 for transit chunks)
    positions: np.ndarray  # (K, 3) mean recorded detector position
    yaw: np.ndarray  # (K,) circular mean of the recorded yaw
    pose_var: np.ndarray  # (K, 3) mean reported pose variance
    counts: np.ndarray  # (K,) total counts
    duration: np.ndarray  # (K,) s
    t_start: np.ndarray  # (K,) s, start of the first frame
    t_end: np.ndarray  # (K,) s, end of the last frame
    n_frames: np.ndarray  # (K,)

    def __len__(self) -> int:
        return len(self.index)

    @property
    def rate(self) -> np.ndarray:
        """Mean count rate (cps)."""
        return self.counts / self.duration

    @property
    def rate_sigma(self) -> np.ndarray:
        """Poisson standard deviation of the mean rate, sqrt(N)/T (at least 1 count's worth)."""
        return np.sqrt(np.maximum(self.counts, 1.0)) / self.duration

    def select(self, mask: np.ndarray) -> DwellSummary:
        return DwellSummary(**{k: getattr(self, k)[mask] for k in self.__dataclass_fields__})


def _summarize(frames: Frames, groups: list[np.ndarray], labels: np.ndarray) -> DwellSummary:
    tot = frames.total_counts.astype(float)
    pos = frames.positions
    pvar = frames.pose_variances
    k = len(groups)
    out = {
        "index": np.asarray(labels, dtype=int),
        "positions": np.zeros((k, 3)),
        "yaw": np.zeros(k),
        "pose_var": np.zeros((k, 3)),
        "counts": np.zeros(k),
        "duration": np.zeros(k),
        "t_start": np.zeros(k),
        "t_end": np.zeros(k),
        "n_frames": np.zeros(k, dtype=int),
    }
    for i, g in enumerate(groups):
        out["positions"][i] = pos[g].mean(axis=0)
        out["yaw"][i] = np.arctan2(np.sin(frames.yaw[g]).mean(), np.cos(frames.yaw[g]).mean())
        out["pose_var"][i] = pvar[g].mean(axis=0)
        out["counts"][i] = tot[g].sum()
        out["duration"][i] = frames.duration[g].sum()
        out["t_start"][i] = frames.t[g[0]] - frames.duration[g[0]]
        out["t_end"][i] = frames.t[g[-1]]
        out["n_frames"][i] = len(g)
    return DwellSummary(**out)


def summarize_dwells(frames: Frames, min_frames: int = 1) -> DwellSummary:
    """One row per dwell index >= 0 (in order of first appearance); transit frames (-1) are dropped."""
    labels = []
    groups = []
    for d in dict.fromkeys(int(v) for v in frames.dwell if v >= 0):
        g = np.flatnonzero(frames.dwell == d)
        if len(g) >= min_frames:
            labels.append(d)
            groups.append(g)
    return _summarize(frames, groups, np.asarray(labels, dtype=int))


def chunk_frames(frames: Frames, seconds: float = 1.0, include_transit: bool = True) -> list[np.ndarray]:
    """Consecutive frames grouped into measurements of at most ``seconds`` (same dwell label throughout)."""
    n = len(frames)
    if n == 0:
        return []
    groups: list[np.ndarray] = []
    start = 0
    acc = 0.0
    for i in range(n):
        new_label = i > start and frames.dwell[i] != frames.dwell[start]
        if new_label or (i > start and acc + frames.duration[i] > seconds + 1e-9):
            groups.append(np.arange(start, i))
            start, acc = i, 0.0
        acc += frames.duration[i]
    groups.append(np.arange(start, n))
    if not include_transit:
        groups = [g for g in groups if frames.dwell[g[0]] >= 0]
    return groups


def summarize_chunks(frames: Frames, seconds: float = 1.0, include_transit: bool = True) -> DwellSummary:
    """A measurement per ``chunk_frames`` group (the 1 Hz measurements of paper 000)."""
    groups = chunk_frames(frames, seconds, include_transit)
    return _summarize(frames, groups, np.array([int(frames.dwell[g[0]]) for g in groups], dtype=int))


def concat_frames(*parts: Frames) -> Frames:
    """Frames appended in order (for partial_fit accumulating a flight)."""
    parts = tuple(p for p in parts if p is not None and len(p))
    if not parts:
        raise ValueError("no frames to concatenate")
    if len(parts) == 1:
        return parts[0]
    return Frames(**{k: np.concatenate([getattr(p, k) for p in parts]) for k in Frames.__dataclass_fields__})
