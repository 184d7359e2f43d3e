"""Shared pieces of the spectrum readers: :class:`Spectrum`, :class:`SpectrumFileError`, number, duration, XML and
energy-calibration helpers (conventions in :mod:`radseek_io.spectrum_io`)."""

from __future__ import annotations

import io
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

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
#: files larger than this are refused before being read (``max_bytes`` raises it): the XML readers hold the
#: whole tree in memory, several times the file
MAX_FILE_BYTES = 64 * 1024 * 1024


class SpectrumFileError(ValueError):
    """A spectrum file that cannot be read; the message names the file and the element that is wrong."""


@dataclass(frozen=True)
class Spectrum:
    """Counts per channel with live time and energy calibration (see the module docstring)."""

    counts: np.ndarray
    live_time_s: float
    real_time_s: float | None = None
    calibration: tuple[float, ...] = (0.0, 1.0)
    #: explicit channel boundaries (n + 1, keV); overrides ``calibration`` when given
    boundaries_keV: np.ndarray | None = None
    start_time: str | None = None
    title: str = ""
    serial: str = ""
    kind: str = "foreground"
    source: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        who = self.source or "<spectrum>"
        c = np.asarray(self.counts, dtype=float)
        if c.ndim != 1 or len(c) == 0:
            raise SpectrumFileError(f"{who}: counts must be a non-empty 1-D array")
        if len(c) > MAX_CHANNELS:
            raise SpectrumFileError(f"{who}: counts: {len(c)} channels, more than {MAX_CHANNELS}")
        check_counts_array(who, "counts", c)
        check_times(who, "live time", self.live_time_s, self.real_time_s)
        object.__setattr__(self, "counts", c)
        if self.boundaries_keV is not None:
            b = np.asarray(self.boundaries_keV, dtype=float)
            if b.shape != (len(c) + 1,) or not np.all(np.isfinite(b)) or np.any(np.diff(b) <= 0):
                raise SpectrumFileError(f"{who}: {len(c) + 1} finite ascending channel boundaries "
                                        f"needed, got {b.shape[0]}")
            object.__setattr__(self, "boundaries_keV", b)
        if not all(math.isfinite(v) for v in self.calibration):
            raise SpectrumFileError(f"{who}: energy calibration {self.calibration} is not finite")

    @property
    def n_channels(self) -> int:
        return len(self.counts)

    def edges_keV(self) -> np.ndarray:
        """(n + 1,) channel boundaries in keV."""
        if self.boundaries_keV is not None:
            return self.boundaries_keV
        return polynomial_edges(self.calibration, self.n_channels)

    def rate(self) -> np.ndarray:
        return self.counts / self.live_time_s

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


# ------------------------------------------------------------------------------------------------ helpers


def _err(path: str | Path, where: str, msg: str) -> SpectrumFileError:
    return SpectrumFileError(f"{path}: {where}: {msg}")


def _float(path: str | Path, where: str, text: str | None) -> float:
    try:
        v = float((text or "").strip())
    except ValueError:
        raise _err(path, where, f"not a number: {text!r}") from None
    if not math.isfinite(v):
        raise _err(path, where, f"not finite: {text!r}")
    return v


def _floats(path: str | Path, where: str, text: str | None) -> list[float]:
    return [_float(path, where, t) for t in (text or "").split()]


_BARE_SECONDS = re.compile(r"^(?:\d+(?:\.\d*)?|\.\d+)$")
_DURATION = re.compile(r"^P(?:(\d+(?:\.\d+)?)D)?(?:T(?:(\d+(?:\.\d+)?)H)?(?:(\d+(?:\.\d+)?)M)?(?:(\d+(?:\.\d+)?)S)?)?$")


def parse_duration(path: str | Path, where: str, text: str | None) -> float:
    """xs:duration (``PT613S``, ``PT1H2M3.5S``) in seconds; a bare number (``300.5``, written by some N42
    exporters) is seconds too."""
    t = (text or "").strip()
    if _BARE_SECONDS.match(t):
        return float(t)
    m = _DURATION.match(t)
    if not m or not any(m.groups()):
        raise _err(path, where, f"not an xs:duration like PT300S: {text!r}")
    d, h, mi, s = (float(g) if g else 0.0 for g in m.groups())
    return ((d * 24 + h) * 60 + mi) * 60 + s


def format_duration(seconds: float) -> str:
    return f"PT{seconds:.10g}S"


def _check_counts(path: str | Path, where: str, values) -> np.ndarray:
    a = np.asarray(values, dtype=float)
    if len(a) == 0:
        raise _err(path, where, "no channel data")
    check_counts_array(str(path), where, a)
    return a


def check_counts_array(who: str, where: str, a: np.ndarray) -> None:
    """Counts finite, >= 0 and <= MAX_COUNTS_PER_CHANNEL; the error names the first bad channel."""
    bad = ~np.isfinite(a) | (a < 0) | (a > MAX_COUNTS_PER_CHANNEL)
    if bad.any():
        i = int(np.argmax(bad))
        raise SpectrumFileError(f"{who}: {where}: channel {i} has {a[i]!r} counts (must be finite, >= 0 and "
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


def read_limited(path: str | Path, max_bytes: int | None = None) -> bytes:
    """The file's bytes, refused (SpectrumFileError) when missing or larger than ``max_bytes`` (default
    MAX_FILE_BYTES) before anything is read (:func:`open_stream`)."""
    with open_stream(path, max_bytes=max_bytes) as fh:
        return fh.read()


def open_stream(path: str | Path, data: bytes | None = None, max_bytes: int | None = None) -> BinaryIO:
    """A binary stream of the file (checked against the size limit as :func:`read_limited`), or of ``data``."""
    if data is not None:
        return io.BytesIO(data)
    p = Path(path)
    limit = MAX_FILE_BYTES if max_bytes is None else int(max_bytes)
    try:
        size = p.stat().st_size
        if size > limit:
            raise SpectrumFileError(f"{p}: {size / 1e6:.1f} MB, over the {limit / 1e6:.0f} MB limit for spectrum "
                                    "files (split the file, or raise the limit with --max-mb)")
        return open(p, "rb")
    except FileNotFoundError:
        raise SpectrumFileError(f"{p}: file not found") from None
    except IsADirectoryError:
        raise SpectrumFileError(f"{p}: is a directory, not a spectrum file") from None
    except PermissionError:
        raise SpectrumFileError(f"{p}: permission denied") from None


def make_spectrum(path: str | Path, where: str, counts, live: float, real: float | None = None, **kw) -> Spectrum:
    """A :class:`Spectrum`, its validation errors re-raised naming ``path`` and ``where``."""
    try:
        return Spectrum(counts, live, real, source=str(path), **kw)
    except SpectrumFileError as exc:
        raise _err(path, where, str(exc).split(": ", 1)[-1]) from None


_PREFIX_USE = re.compile(rb"</?([A-Za-z_][\w.-]*):[A-Za-z_]|\s([A-Za-z_][\w.-]*):[A-Za-z_][\w.-]*\s*=")
_FIRST_TAG = re.compile(rb"<[A-Za-z_][\w.:-]*")


def _parse_xml(path: str | Path, data: bytes) -> ET.Element:
    """The XML tree. InterSpec (SpecUtils) writes its ``<DHS:InterSpec>`` section into N42 files without
    declaring the ``DHS`` prefix, which expat rejects; such undeclared prefixes are bound to a placeholder
    namespace on the root element and the file parsed again (namespaces are ignored by the readers)."""
    try:
        return ET.fromstring(data)
    except ET.ParseError as exc:
        err = exc
    if "unbound prefix" in str(err):
        declared = set(re.findall(rb"xmlns:([A-Za-z_][\w.-]*)\s*=", data))
        used = {a or b for a, b in _PREFIX_USE.findall(data)} - declared - {b"xml", b"xmlns"}
        m = _FIRST_TAG.search(data)
        if used and m:
            decl = b"".join(b' xmlns:%s="urn:radseek:undeclared:%s"' % (u, u) for u in sorted(used))
            try:
                return ET.fromstring(data[: m.end()] + decl + data[m.end():])
            except ET.ParseError:
                pass
    raise SpectrumFileError(f"{path}: not well-formed XML ({err})") from None


def _poly_cal(path: str | Path, where: str, coefs, n: int) -> tuple[float, ...]:
    """A polynomial energy calibration checked over ``n`` channels. All zeros (what an uncalibrated MCA writes,
    e.g. a digiBASE's ``$MCA_CAL``) means none: channel numbers, as for a file without a calibration. Otherwise
    the channel edges must rise, or the file's calibration is garbage and reading it would misplace every peak."""
    c = tuple(float(v) for v in coefs)
    if not c or all(v == 0 for v in c):
        return (0.0, 1.0)
    with np.errstate(all="ignore"):
        e = polynomial_edges(c, n)
    if not _rising(e):
        raise _err(path, where, f"energy calibration {c} does not rise over channels 0..{n}")
    return c


def polynomial_edges(cal: tuple[float, ...], n: int) -> np.ndarray:
    """(n + 1,) channel edges in keV of the polynomial calibration ``cal``: E(i) = c0 + c1 i + c2 i^2 + ..."""
    i = np.arange(n + 1, dtype=float)
    return sum(c * i**k for k, c in enumerate(cal)) * np.ones_like(i)


def _rising(edges: np.ndarray) -> bool:
    """Channel edges that are finite and rise strictly (a usable energy calibration)."""
    return bool(np.all(np.isfinite(edges)) and np.all(np.diff(edges) > 0))


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _child(el: ET.Element, name: str) -> ET.Element | None:
    for c in el:
        if _local(c.tag) == name:
            return c
    return None


def _children(el: ET.Element, name: str) -> list[ET.Element]:
    return [c for c in el if _local(c.tag) == name]


def _find(el: ET.Element, name: str) -> ET.Element | None:
    for c in el.iter():
        if _local(c.tag) == name:
            return c
    return None
