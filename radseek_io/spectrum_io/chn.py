"""Ortec binary .chn (ORTEC software file structure manual)."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np

from .core import Spectrum, _check_counts, _err, _poly_cal, read_limited

_CHN_HEADER = struct.Struct("<hhh2sii8s4shh")


def read_chn(path: str | Path, data: bytes | None = None) -> list[Spectrum]:
    """An Ortec binary .chn file."""
    data = read_limited(path) if data is None else data
    if len(data) < _CHN_HEADER.size:
        raise _err(path, "header", f"{len(data)} bytes, the .chn header alone is {_CHN_HEADER.size}")
    tag, _mca, _seg, secs, real_t, live_t, date, tim, first, n = _CHN_HEADER.unpack_from(data)
    if tag != -1:
        raise _err(path, "header byte 0", f"type must be -1 for .chn, got {tag}")
    if n <= 0:
        raise _err(path, "header byte 30", f"channel count must be > 0, got {n}")
    end = _CHN_HEADER.size + 4 * n
    if len(data) < end:
        raise _err(path, f"channel data (bytes 32..{end})", f"file ends at byte {len(data)}")
    counts = np.frombuffer(data, "<i4", n, _CHN_HEADER.size).astype(float)
    counts = _check_counts(path, "channel data", list(counts))
    live, real = live_t * 0.02, real_t * 0.02
    if live <= 0:
        raise _err(path, "header byte 12 (live time)", f"must be > 0, got {live_t} ticks")
    cal: tuple[float, ...] = (0.0, 1.0)
    if len(data) >= end + 16:
        ttag = struct.unpack_from("<h", data, end)[0]
        if ttag in (-101, -102):
            c0, c1, c2 = struct.unpack_from("<fff", data, end + 4)
            cal = (c0, c1, c2) if ttag == -102 else (c0, c1)
            if not all(math.isfinite(c) for c in cal):
                raise _err(path, f"trailer byte {end + 4}", f"energy calibration not finite: {cal}")
            cal = _poly_cal(path, f"trailer byte {end + 4} (energy calibration)", cal, n + max(first, 0))
        else:
            raise _err(path, f"trailer byte {end}", f"tag must be -101 or -102, got {ttag}")
    start = None
    try:
        d, t = date.decode("ascii"), tim.decode("ascii")
        start = f"{d[:7]} {t[:2]}:{t[2:]}:{secs.decode('ascii')}"
    except UnicodeDecodeError:
        pass
    if first:
        counts = np.r_[np.zeros(first), counts]
    return [Spectrum(counts, live, real, cal, None, start, "", "", "foreground", str(path))]


def write_chn(path: str | Path, sp: Spectrum) -> Path:
    """An Ortec .chn with a -102 trailer (used by the tests)."""
    cal = tuple(sp.calibration) + (0.0,) * (3 - len(sp.calibration))
    head = _CHN_HEADER.pack(-1, 1, 1, b"00", round((sp.realtime or sp.livetime) / 0.02),
                            round(sp.livetime / 0.02), b"01JAN70*", b"0000", 0, sp.n_channels)
    body = np.asarray(sp.counts, dtype="<i4").tobytes()
    trailer = struct.pack("<hhfff", -102, 0, *cal[:3]) + bytes(512 - 16)
    Path(path).write_bytes(head + body + trailer)
    return Path(path)
