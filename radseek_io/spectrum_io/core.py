"""Shared pieces of the spectrum readers: number, duration, XML and energy-calibration helpers (conventions in
:mod:`radseek_io.spectrum_io`). :class:`Spectrum` and :class:`SpectrumFileError` are the contracts'
(:mod:`radseek.spectrum`), re-exported here for the readers."""

from __future__ import annotations

import io
import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import BinaryIO

import numpy as np

from radseek.spectrum import (  # noqa: F401 (re-exported: the readers' shared names)
    LIVE_OVER_REAL_FRACTION,
    LIVE_OVER_REAL_S,
    MAX_CHANNELS,
    MAX_COUNTS_PER_CHANNEL,
    MAX_TIME_S,
    Spectrum,
    SpectrumFileError,
    check_counts_array,
    check_times,
    polynomial_edges,
)

#: files larger than this are refused before being read (``max_bytes`` raises it): the XML readers hold the
#: whole tree in memory, several times the file
MAX_FILE_BYTES = 64_000_000  # 64 MB as --max-mb counts them (10^6 bytes)

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
