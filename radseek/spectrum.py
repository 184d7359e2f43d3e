"""The one spectrum type of radseek: counts per channel with their energy bins and times, like becquerel's
``Spectrum`` (``counts``, ``bin_edges_kev``, ``livetime``, ``realtime``).

A frame of the 32-channel board (``radseek.frame_record.FrameRecord.spectrum``: integer counts, the
scenario's channel edges, the frame's duration as ``realtime``, ``livetime`` unknown to the board) and a
spectrum read from a file (:mod:`radseek_io.spectrum_io`: any number of channels, a live time, an energy
calibration or explicit edges, and the file's metadata) are both a :class:`Spectrum`.

Counts are kept as integers when given as an integer array (a frame's exact counts), else as floats.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: counts above this in one channel are not a measurement (a RadiaCode's 18-day accumulated history holds ~1e9
#: in all channels together); 1e300 or a corrupted number is refused naming the channel
MAX_COUNTS_PER_CHANNEL = 1e12
#: live or real times above this (3.2 years) are refused: a corrupted duration, not a measurement
MAX_TIME_S = 1e8
#: a live time may exceed the real time by this fraction plus LIVE_OVER_REAL_S (rounding in the writers)
LIVE_OVER_REAL_FRACTION = 0.01
LIVE_OVER_REAL_S = 1.0
#: more channels than this is a corrupted channel index or count, not an MCA
MAX_CHANNELS = 65536


class SpectrumFileError(ValueError):
    """A spectrum that cannot be: the message names the file (or spectrum) and the element that is wrong."""


@dataclass(frozen=True)
class Spectrum:
    """Counts per channel with their energy bins and live and real time (s).

    ``livetime`` is None when unknown (the board reports none: dead time loses counts silently); ``realtime``
    None when a file gives none. ``bin_edges_kev`` (n + 1, ascending) are the channel boundaries; without
    them the polynomial ``calibration`` (E(i) = c0 + c1 i + ..., lower channel edge) gives them.
    """

    counts: np.ndarray
    livetime: float | None = None
    realtime: float | None = None
    calibration: tuple[float, ...] = (0.0, 1.0)
    #: explicit channel boundaries (n + 1, keV); overrides ``calibration`` when given
    bin_edges_kev: np.ndarray | None = None
    start_time: str | None = None
    title: str = ""
    serial: str = ""
    kind: str = "foreground"
    source: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        who = self.source or "<spectrum>"
        c = np.asarray(self.counts)
        if c.dtype.kind not in "iu":
            c = c.astype(float)
        if c.ndim != 1 or len(c) == 0:
            raise SpectrumFileError(f"{who}: counts must be a non-empty 1-D array")
        if len(c) > MAX_CHANNELS:
            raise SpectrumFileError(f"{who}: counts: {len(c)} channels, more than {MAX_CHANNELS}")
        check_counts_array(who, "counts", c)
        if self.livetime is not None:
            check_times(who, "live time", self.livetime, self.realtime)
        elif self.realtime is not None:
            check_times(who, "real time", self.realtime, None)
        object.__setattr__(self, "counts", c)
        if self.bin_edges_kev is not None:
            b = np.asarray(self.bin_edges_kev, dtype=float)
            if b.shape != (len(c) + 1,) or not np.all(np.isfinite(b)) or np.any(np.diff(b) <= 0):
                raise SpectrumFileError(f"{who}: {len(c) + 1} finite ascending channel boundaries "
                                        f"needed, got {b.shape[0] if b.ndim else 0}")
            object.__setattr__(self, "bin_edges_kev", b)
        if not all(math.isfinite(v) for v in self.calibration):
            raise SpectrumFileError(f"{who}: energy calibration {self.calibration} is not finite")

    @property
    def n_channels(self) -> int:
        return len(self.counts)

    @property
    def total(self) -> int | float:
        s = self.counts.sum()
        return int(s) if self.counts.dtype.kind in "iu" else float(s)

    @property
    def cps(self) -> np.ndarray:
        """Count rate per channel over the real time (a frame's duration)."""
        return self.counts / self.realtime

    def edges_keV(self) -> np.ndarray:
        """(n + 1,) channel boundaries in keV."""
        if self.bin_edges_kev is not None:
            return self.bin_edges_kev
        return polynomial_edges(self.calibration, self.n_channels)

    def rate(self) -> np.ndarray:
        """Count rate per channel over the live time."""
        return self.counts / self.livetime

    def rebin(self, edges_keV: np.ndarray, overflow: bool = True) -> np.ndarray:
        """Counts in the bins ``edges_keV`` (m + 1 edges), channels split linearly in energy; with ``overflow``
        the last bin is open above (as channel 31 of the board)."""
        e = self.edges_keV()
        keep = np.r_[True, np.diff(e) > 0]
        cum = np.r_[0.0, np.cumsum(self.counts)]
        ce = np.interp(np.asarray(edges_keV, dtype=float), e[keep], cum[keep])
        out = np.diff(ce)
        if overflow:
            out[-1] = cum[-1] - ce[-2]
        return out


def check_counts_array(who: str, where: str, a: np.ndarray) -> None:
    """Counts finite, >= 0 and <= MAX_COUNTS_PER_CHANNEL; the error names the first bad channel."""
    bad = ~np.isfinite(a) | (a < 0) | (a > MAX_COUNTS_PER_CHANNEL)
    if bad.any():
        i = int(np.argmax(bad))
        raise SpectrumFileError(f"{who}: {where}: channel {i} has {float(a[i]):g} counts (must be finite, >= 0 and "
                                f"<= {MAX_COUNTS_PER_CHANNEL:g})")


def check_times(who: str, where: str, live: float, real: float | None) -> None:
    """Live time in (0, MAX_TIME_S], real time likewise when given, live <= real (plus a rounding margin)."""
    if not (isinstance(live, (int, float)) and math.isfinite(live) and 0 < live <= MAX_TIME_S):
        raise SpectrumFileError(f"{who}: {where} must be > 0 and <= {MAX_TIME_S:g} s, got {live!r}")
    if real is not None:
        if not (isinstance(real, (int, float)) and math.isfinite(real) and 0 < real <= MAX_TIME_S):
            raise SpectrumFileError(f"{who}: real time must be > 0 and <= {MAX_TIME_S:g} s, got {real!r}")
        if live > real * (1 + LIVE_OVER_REAL_FRACTION) + LIVE_OVER_REAL_S:
            raise SpectrumFileError(f"{who}: {where} {live:g} s exceeds the real time {real:g} s")


def polynomial_edges(cal: tuple[float, ...], n: int) -> np.ndarray:
    """(n + 1,) channel edges in keV of the polynomial calibration ``cal``: E(i) = c0 + c1 i + c2 i^2 + ..."""
    i = np.arange(n + 1, dtype=float)
    return sum(c * i**k for k, c in enumerate(cal)) * np.ones_like(i)
