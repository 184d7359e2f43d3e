"""RadiaCode spectrogram (``.rcspg``), as the RadiaCode apps write it.

Layout (radiacode-tools ``rc_files.RcSpectrogram``, MIT; checked on its ``tests/data/K40.rcspg``):

1. a header line of tab-separated ``key: value`` fields: ``Spectrogram`` (name), ``Time`` (local time),
   ``Timestamp`` (Windows FILETIME: 100 ns ticks since 1601-01-01 UTC), ``Accumulation time`` (s, the sum of
   the rows' durations),
   ``Channels``, ``Device serial``, ``Flags`` (bit 0 clear: the recording was interrupted and resumed),
   ``Comment``;
2. ``Spectrum:`` and hex bytes: uint32 duration (s), float32 a0 a1 a2 (the energy calibration, lower channel edge
   E(i) = a0 + a1 i + a2 i^2 keV), then one uint32 count per channel. This is the device's *accumulated* spectrum
   since its last reset (days or weeks), not the recording: kind ``accumulated``;
3. one line per time row: FILETIME at the row's end, its duration (s), then the counts of that interval (a
   differential spectrum; trailing zero channels left out), tab separated: kind ``row``.

The rows are streamed (:func:`iter_rows`): their sum is the recording (kind ``foreground``, live time the sum of
the durations), and no more than one row is held in memory at a time.
"""

from __future__ import annotations

import binascii
import datetime as dt
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .core import (
    MAX_CHANNELS,
    MAX_TIME_S,
    Spectrum,
    _err,
    _poly_cal,
    check_counts_array,
    make_spectrum,
    open_stream,
)

FILETIME_EPOCH = dt.datetime(1601, 1, 1, tzinfo=dt.UTC)
#: FILETIME ticks per second
TICKS = 10_000_000
_HEADER_KEYS = ("Spectrogram", "Timestamp", "Accumulation time", "Channels")


def filetime_to_unix(ticks: int) -> float:
    return ticks / TICKS - 11_644_473_600.0


def iso(unix_s: float) -> str:
    try:
        return dt.datetime.fromtimestamp(unix_s, dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    except (OverflowError, OSError, ValueError):
        return ""


@dataclass
class Row:
    """One time row: its end (unix s, the file's clock), duration (s) and counts (``channels`` long)."""

    line: int
    end_s: float
    duration_s: float
    counts: np.ndarray


@dataclass
class Spectrogram:
    """The header and accumulated spectrum of an .rcspg; the rows come from :func:`iter_rows`."""

    path: str
    name: str
    start_s: float
    accumulation_s: float
    channels: int
    serial: str
    flags: str
    comment: str
    calibration: tuple[float, ...]
    accumulated: Spectrum | None
    meta: dict = field(default_factory=dict)


def _lines(path: str | Path, max_bytes: int | None, data: bytes | None = None) -> Iterator[tuple[int, str]]:
    with open_stream(path, data, max_bytes) as f:
        for i, raw in enumerate(f, 1):
            try:
                yield i, raw.decode("utf-8-sig" if i == 1 else "utf-8")
            except UnicodeDecodeError:
                raise _err(path, f"line {i}", "not UTF-8 text (not a RadiaCode spectrogram?)") from None


def read_header(path: str | Path, max_bytes: int | None = None, data: bytes | None = None) -> Spectrogram:
    """Header line and accumulated spectrum (lines 1 and 2)."""
    it = _lines(path, max_bytes, data)
    first = next(it, None)
    second = next(it, None)
    if first is None or not first[1].startswith("Spectrogram:"):
        raise _err(path, "line 1", "must start with 'Spectrogram:' (a RadiaCode .rcspg)")
    fields: dict[str, str] = {}
    for part in first[1].rstrip("\r\n").split("\t"):
        k, sep, v = part.partition(":")
        if sep:
            fields[k.strip()] = v.strip()
    for k in _HEADER_KEYS:
        if k not in fields:
            raise _err(path, "line 1", f"header field {k!r} missing")
    try:
        ticks = int(fields["Timestamp"])
        acc_time = float(int(fields["Accumulation time"]))
        n = int(fields["Channels"])
    except ValueError:
        raise _err(path, "line 1", "Timestamp, Accumulation time and Channels must be integers") from None
    if not 0 < n <= MAX_CHANNELS:
        raise _err(path, "line 1 Channels", f"{n} (1..{MAX_CHANNELS})")
    if not 0 <= acc_time <= MAX_TIME_S:
        raise _err(path, "line 1 Accumulation time", f"{acc_time:g} s (0..{MAX_TIME_S:g})")
    if not 0 < ticks < 2**63:
        raise _err(path, "line 1 Timestamp", f"{ticks} is not a FILETIME")
    if second is None or not second[1].startswith("Spectrum:"):
        raise _err(path, "line 2", "must start with 'Spectrum:' (the accumulated spectrum)")
    try:
        raw = binascii.unhexlify(second[1][len("Spectrum:"):].replace(" ", "").strip())
    except (binascii.Error, ValueError):
        raise _err(path, "line 2", "accumulated spectrum is not hex bytes") from None
    if len(raw) != 16 + 4 * n:
        raise _err(path, "line 2", f"{len(raw)} bytes; {16 + 4 * n} needed (duration, 3 coefficients, {n} counts)")
    acc_dur, a0, a1, a2 = struct.unpack_from("<I3f", raw)
    cal = _poly_cal(path, "line 2 energy calibration", (a0, a1, a2), n)
    counts = np.frombuffer(raw, "<u4", n, 16).astype(float)
    start = filetime_to_unix(ticks)
    acc = None
    if acc_dur:  # a device reset just before the recording has nothing accumulated
        acc = make_spectrum(path, "line 2 (accumulated spectrum)", counts, float(acc_dur), None, calibration=cal,
                            title=fields.get("Spectrogram", ""), serial=fields.get("Device serial", ""),
                            kind="accumulated")
    elif counts.any():
        raise _err(path, "line 2", "accumulated spectrum has counts but a duration of 0 s")
    return Spectrogram(str(path), fields["Spectrogram"], start, acc_time, n, fields.get("Device serial", ""),
                       fields.get("Flags", ""), fields.get("Comment", ""), cal, acc)


def iter_rows(path: str | Path, header: Spectrogram | None = None, max_bytes: int | None = None,
              data: bytes | None = None) -> Iterator[Row]:
    """The time rows in file order, each checked (FILETIME, duration 0 < d <= 1e8 s, counts); rows whose end
    times do not increase are refused naming the line."""
    hdr = header or read_header(path, max_bytes, data)
    n = hdr.channels
    prev_end = None
    for i, text in _lines(path, max_bytes, data):
        if i <= 2 or not text.strip():
            continue
        parts = text.split()
        where = f"line {i}"
        if len(parts) < 2:
            raise _err(path, where, "a row needs a FILETIME and a duration")
        if len(parts) > n + 2:
            raise _err(path, where, f"{len(parts) - 2} counts for {n} channels")
        try:
            vals = [int(v) for v in parts]
        except ValueError:
            raise _err(path, where, "values must be integers") from None
        ticks, dur = vals[0], vals[1]
        if not 0 < ticks < 2**63:
            raise _err(path, where + " timestamp", f"{ticks} is not a FILETIME")
        if not 0 < dur <= MAX_TIME_S:
            raise _err(path, where + " duration", f"{dur} s (must be > 0 and <= {MAX_TIME_S:g})")
        counts = np.zeros(n)
        try:
            counts[: len(parts) - 2] = np.asarray(vals[2:], dtype=float)
        except (OverflowError, ValueError):
            raise _err(path, where, "count out of range") from None
        check_counts_array(str(path), where, counts)
        end = filetime_to_unix(ticks)
        if prev_end is not None and end <= prev_end:
            raise _err(path, where, f"row ends at {iso(end)}, not after the row before ({iso(prev_end)})")
        prev_end = end
        yield Row(i, end, float(dur), counts)


def read_rcspg(path: str | Path, data: bytes | None = None, max_bytes: int | None = None) -> list[Spectrum]:
    """The recording (sum of the rows, kind ``foreground``) and the device's accumulated spectrum (kind
    ``accumulated``); ``meta`` of the foreground holds the row summary (``rows``, ``first_row_start``,
    ``last_row_end``). The file is streamed from ``path`` (or ``data``), one row at a time."""
    hdr = read_header(path, max_bytes, data)
    total = np.zeros(hdr.channels)
    live = 0.0
    n_rows = 0
    first = last = None
    for row in iter_rows(path, hdr, max_bytes, data):
        total += row.counts
        live += row.duration_s
        n_rows += 1
        first = row.end_s - row.duration_s if first is None else first
        last = row.end_s
    if n_rows == 0:
        raise _err(path, "rows", "no time rows after the accumulated spectrum (line 3 on)")
    real = (last - first) if last is not None and first is not None and last > first else None
    if real is not None and live > real:
        real = None  # the rows' clock and durations disagree (a row of a resumed recording): no real time
    meta = {"rows": n_rows, "first_row_start": iso(first), "last_row_end": iso(last),
            "header_accumulation_time_s": hdr.accumulation_s, "flags": hdr.flags}
    fg = make_spectrum(path, "rows (their sum)", total, live, real, calibration=hdr.calibration,
                       start_time=iso(first), title=hdr.name, serial=hdr.serial, kind="foreground", meta=meta)
    return [fg] + ([hdr.accumulated] if hdr.accumulated is not None else [])
