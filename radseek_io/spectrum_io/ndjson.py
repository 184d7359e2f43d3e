"""radiacode-tools logs (``rcmultispg``, newline-delimited JSON: one record a line), streamed.

Record schema, from radiacode-tools (github.com/ckuethe/radiacode-tools, MIT) ``src/rcmultispg.py`` and
``radiacode_tools/rc_utils.specdata_to_dict``, checked on its ``tests/data/broken_arrow_errrr_airplane.ndjson``
and ``xray.ndjson``:

- **spectrum** (polled every ``--interval`` s): ``timestamp`` (host clock, unix s), ``serial_number``,
  ``duration`` (s the device has accumulated, whole seconds), ``calibration`` ``[a0, a1, a2]`` (lower channel
  edge E(i) = a0 + a1 i + a2 i^2 keV), ``counts`` (*cumulative* since the device's last spectrum reset). Later
  versions write the dataclass instead: ``{"_type": "SpecData", "dt": ISO time, "serial_number",
  "spectrum": {"duration", "a0", "a1", "a2", "counts"}}``; both are read.
- **GNSS fix** (gpsd TPV): ``gnss`` (false: no fix), ``time`` (receiver UTC, ISO), ``mode`` (2: 2-D, 3: 3-D),
  ``lat``, ``lon``, ``alt`` (m), ``epc``, ``sep``, ``speed``, ``track``, ``climb``, newer files ``hosttime``
  (host clock, preferred: the spectra use it); or ``{"_type": "GpsData", "payload": {...}}``.
- **device records**: ``type`` ``RealTimeData`` / ``DoseRateDB`` / ``RareData`` / ... with ``count_rate``,
  ``dose_rate``, ``dose``, ``temperature``, ``charge_level`` (``_type`` ``RtData`` in later versions): counted.

Consecutive spectra of one device are differenced into frames (:class:`Frame`): live time the host-clock gap
(the device's duration counter has whole seconds only), checked against the device's own duration difference.
A record whose counts or duration went down is a device reset, one whose duration difference disagrees with the
clock (by more than 1.5 s + 10 %) a restart or dropped poll, one with a new calibration a recalibration: each
starts a new baseline and gives no frame (counted in :class:`Log`). Spectra not later than the one before
(duplicate or out-of-order timestamps) are skipped and counted. Nothing is sorted, so memory stays at one
record whatever the file's length.

GNSS position error (1 sigma per axis, m), from the first of these present in a fix: gpsd ``epx``/``epy``
(95 %, per axis: / 1.96), ``eph`` (95 % horizontal radius: / 2.45), ``accuracy`` (RadiaCode / Android, 68 %
radius: / 1.52), ``hdop`` (x 5 m), ``sep`` (95 % spherical: / 2.80); none: :data:`DEFAULT_SIGMA_H_M`.
Vertical: ``epv`` / 1.96, else ``sep`` / 2.80, else twice the horizontal.
"""

from __future__ import annotations

import datetime as dt
import json
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .core import (
    MAX_CHANNELS,
    MAX_TIME_S,
    Spectrum,
    SpectrumFileError,
    _err,
    _poly_cal,
    check_counts_array,
    make_spectrum,
    open_stream,
    read_limited,
)

#: horizontal 1-sigma position error (m) assumed for a fix that states no quality (a phone-grade receiver)
DEFAULT_SIGMA_H_M = 5.0
#: a frame is refused when the device's duration difference and the host clock gap differ by more than this
#: (s) plus TIMING_TOLERANCE_FRACTION of the gap
TIMING_TOLERANCE_S = 1.5
TIMING_TOLERANCE_FRACTION = 0.10
_UNIX_MIN, _UNIX_MAX = 0.0, 4.1e9  # 1970 .. 2100


@dataclass
class GnssFix:
    line: int
    t: float  # unix s, host clock when the fix has ``hosttime``, else the receiver's
    lat: float
    lon: float
    alt: float | None
    sigma_h: float
    sigma_v: float
    track_deg: float | None = None
    speed: float | None = None


@dataclass
class Frame:
    """One frame: the difference of two consecutive cumulative spectra (native channels)."""

    line: int
    start_s: float
    end_s: float
    counts: np.ndarray
    calibration: tuple[float, ...] = ()

    @property
    def live_s(self) -> float:
        return self.end_s - self.start_s


@dataclass
class Log:
    path: str
    serial: str = ""
    calibration: tuple[float, ...] = ()
    channels: int = 0
    spectrum_records: int = 0
    frames: int = 0
    frame_live_s: float = 0.0
    first_frame_start: float | None = None
    last_frame_end: float | None = None
    foreground: np.ndarray | None = None
    last_record: Spectrum | None = None
    gnss: list[GnssFix] = field(default_factory=list)
    gnss_without_fix: int = 0
    device_records: Counter = field(default_factory=Counter)
    other_serials: Counter = field(default_factory=Counter)
    resets: int = 0
    timing_breaks: int = 0
    recalibrations: int = 0
    out_of_order: int = 0
    notes: list[str] = field(default_factory=list)


def _num(path, where: str, rec: dict, key: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    v = rec.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise _err(path, f"{where} field {key!r}", f"must be a number in [{lo:g}, {hi:g}], got {v!r}")
    return float(v)


def _opt(rec: dict, key: str) -> float | None:
    v = rec.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
        return None
    return float(v)


def _iso_time(path, where: str, text) -> float:
    if not isinstance(text, str):
        raise _err(path, f"{where} field 'time'", f"must be an ISO time, got {text!r}")
    try:
        t = dt.datetime.fromisoformat(text.strip())
    except ValueError:
        raise _err(path, f"{where} field 'time'", f"not an ISO time: {text!r}") from None
    if t.tzinfo is None:
        t = t.replace(tzinfo=dt.UTC)
    return t.timestamp()


def sigmas(rec: dict) -> tuple[float, float]:
    """(horizontal, vertical) 1-sigma position error of a fix (see the module docstring)."""
    epx, epy, eph, acc, hdop, sep = (_opt(rec, k) for k in ("epx", "epy", "eph", "accuracy", "hdop", "sep"))
    if epx is not None and epy is not None:
        h = max(epx, epy) / 1.96
    elif eph is not None:
        h = eph / 2.45
    elif acc is not None:
        h = acc / 1.52
    elif hdop is not None:
        h = hdop * 5.0
    elif sep is not None:
        h = sep / 2.80
    else:
        h = DEFAULT_SIGMA_H_M
    epv = _opt(rec, "epv")
    v = epv / 1.96 if epv is not None else (sep / 2.80 if sep is not None else 2 * h)
    return max(h, 0.1), max(v, 0.1)


def _spectrum_fields(path, where: str, rec: dict) -> tuple[float, str, float, list, object] | None:
    """(time, serial, duration, calibration, counts) of a spectrum record, or None if it is not one."""
    if "counts" in rec and "duration" in rec:
        t = _num(path, where, rec, "timestamp", _UNIX_MIN, _UNIX_MAX)
        cal = rec.get("calibration")
        return t, str(rec.get("serial_number", "")), _num(path, where, rec, "duration", 0, MAX_TIME_S), cal, \
            rec["counts"]
    if rec.get("_type") == "SpecData" and isinstance(rec.get("spectrum"), dict):
        sp = rec["spectrum"]
        if isinstance(rec.get("dt"), str):
            t = _iso_time(path, where, rec["dt"])
        else:
            t = _num(path, where, rec, "time", _UNIX_MIN, _UNIX_MAX)
        cal = [sp.get(k) for k in ("a0", "a1", "a2")]
        return t, str(rec.get("serial_number", "")), _num(path, where + " spectrum", sp, "duration", 0, MAX_TIME_S), \
            cal, sp.get("counts")
    return None


def _counts(path, where: str, counts) -> np.ndarray:
    if not isinstance(counts, list) or not 0 < len(counts) <= MAX_CHANNELS:
        raise _err(path, f"{where} field 'counts'", f"must be a list of 1..{MAX_CHANNELS} numbers")
    if not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in counts):
        raise _err(path, f"{where} field 'counts'", "must hold numbers only")
    try:
        a = np.asarray(counts, dtype=float)
    except (OverflowError, ValueError):
        raise _err(path, f"{where} field 'counts'", "number out of range") from None
    check_counts_array(str(path), f"{where} field 'counts'", a)
    return a


def _reject_constant(name: str):
    raise ValueError(f"{name} is not a number")


def read_json_object(path: str | Path, data: bytes | None = None) -> dict:
    """A JSON document whose top level is an object (RadiaCode app JSON, NPES): read within the size limit, strict
    (no NaN or Infinity), a SpectrumFileError naming the file otherwise."""
    data = read_limited(path) if data is None else data
    try:
        doc = json.loads(data.decode("utf-8-sig"), parse_constant=_reject_constant)
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise _err(path, "JSON", f"not a JSON document ({str(exc)[:80]})") from None
    if not isinstance(doc, dict):
        raise _err(path, "JSON", "the document must be an object")
    return doc


def scan(path: str | Path, serial: str | None = None, on_frame: Callable[[Frame], None] | None = None,
         max_bytes: int | None = None, data: bytes | None = None) -> Log:
    """Stream a log: GNSS fixes kept, spectra of ``serial`` (default: the first device seen) differenced into
    frames handed to ``on_frame`` one at a time and summed into ``Log.foreground``."""
    p = Path(path)
    log = Log(str(p))
    prev: tuple[float, float, np.ndarray, tuple] | None = None  # time, duration, counts, calibration
    pending: SpectrumFileError | None = None
    with open_stream(p, data, max_bytes) as f:
        for i, raw in enumerate(f, 1):
            if pending is not None:
                raise pending
            where = f"line {i}"
            if not raw.strip():
                continue
            try:
                rec = json.loads(raw, parse_constant=_reject_constant)
            except (ValueError, RecursionError) as exc:
                # a logger killed mid-write leaves a cut last line: skipped (noted); anywhere else an error
                pending = _err(p, where, f"not a JSON record ({str(exc)[:80]})")
                continue
            if not isinstance(rec, dict):
                raise _err(p, where, "a record must be a JSON object")
            if rec.get("_type") == "GpsData" and isinstance(rec.get("payload"), dict):
                rec = rec["payload"]
            if "gnss" in rec:
                _gnss(p, where, i, rec, log)
                continue
            fields = _spectrum_fields(p, where, rec)
            if fields is None:
                kind = rec.get("type") if isinstance(rec.get("type"), str) else rec.get("_type")
                log.device_records[str(kind) if kind else "unknown"] += 1
                continue
            t, sn, dur, cal_raw, counts_raw = fields
            if serial is None:
                serial = sn
            if sn != serial:
                log.other_serials[sn] += 1
                continue
            log.serial = sn
            counts = _counts(p, where, counts_raw)
            if not isinstance(cal_raw, list) or len(cal_raw) < 2:
                raise _err(p, f"{where} field 'calibration'", f"must be [a0, a1, a2], got {cal_raw!r}")
            cal_vals = []
            for k, c in enumerate(cal_raw):
                if isinstance(c, bool) or not isinstance(c, (int, float)) or not math.isfinite(c):
                    raise _err(p, f"{where} field 'calibration'", f"coefficient {k} is {c!r}")
                cal_vals.append(float(c))
            cal = _poly_cal(p, f"{where} field 'calibration'", cal_vals, len(counts))
            log.spectrum_records += 1
            if log.channels and len(counts) != log.channels:
                raise _err(p, f"{where} field 'counts'", f"{len(counts)} channels; earlier records have "
                           f"{log.channels}")
            log.channels = len(counts)
            if dur > 0:
                log.last_record = make_spectrum(p, where, counts, dur, None, calibration=cal, serial=sn,
                                                kind="accumulated", start_time=_iso(t - dur))
            if log.foreground is None:
                log.foreground = np.zeros(len(counts))
                log.calibration = cal
            if prev is None:
                prev = (t, dur, counts, cal)
                continue
            pt, pdur, pcounts, pcal = prev
            if t <= pt:
                log.out_of_order += 1  # duplicate or out-of-order: keep the earlier baseline
                continue
            diff = counts - pcounts
            gap, ddur = t - pt, dur - pdur
            if cal != pcal:
                log.recalibrations += 1
                if log.recalibrations == 1:
                    log.notes.append(f"{where}: the calibration changed; the summed spectrum keeps the first "
                                     "calibration's channels")
            elif ddur < 0 or np.any(diff < 0):
                log.resets += 1
            elif abs(ddur - gap) > TIMING_TOLERANCE_S + TIMING_TOLERANCE_FRACTION * gap:
                log.timing_breaks += 1
            else:
                frame = Frame(i, pt, t, diff, cal)
                log.foreground += diff
                log.frames += 1
                log.frame_live_s += gap
                log.first_frame_start = pt if log.first_frame_start is None else log.first_frame_start
                log.last_frame_end = t
                if on_frame is not None:
                    on_frame(frame)
            prev = (t, dur, counts, cal)
    if pending is not None:
        log.notes.append(f"{pending.args[0].split(': ', 1)[-1]} (the last line: skipped as cut off)")
    if log.spectrum_records == 0 and not log.gnss:
        raise _err(p, "records", "no spectrum and no GNSS record (not a radiacode-tools log?)")
    log.gnss.sort(key=lambda g: g.t)
    return log


def _gnss(p: Path, where: str, line: int, rec: dict, log: Log) -> None:
    mode = rec.get("mode")
    if rec.get("gnss") is not True or (isinstance(mode, (int, float)) and mode < 2):
        log.gnss_without_fix += 1
        return
    t = rec.get("hosttime")
    if isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t) and _UNIX_MIN < t < _UNIX_MAX:
        t = float(t)
    else:
        t = _iso_time(p, where, rec.get("time"))
    lat = _num(p, where, rec, "lat", -90, 90)
    lon = _num(p, where, rec, "lon", -180, 180)
    alt = rec.get("alt")
    alt = float(alt) if isinstance(alt, (int, float)) and not isinstance(alt, bool) and -1e4 < alt < 1e5 else None
    if isinstance(mode, (int, float)) and mode == 2:
        alt = None  # a 2-D fix's altitude is not measured
    h, v = sigmas(rec)
    log.gnss.append(GnssFix(line, t, lat, lon, alt, h, v, _opt(rec, "track"), _opt(rec, "speed")))


def _iso(unix_s: float) -> str:
    try:
        return dt.datetime.fromtimestamp(unix_s, dt.UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")[:-4] + "Z"
    except (OverflowError, OSError, ValueError):
        return ""


def read_ndjson(path: str | Path, data: bytes | None = None, max_bytes: int | None = None) -> list[Spectrum]:
    """The frames' sum (kind ``foreground``, live time the sum of the frames') and the last cumulative record
    (kind ``accumulated``). The file is streamed from ``path`` (or ``data``), one record at a time."""
    log = scan(path, max_bytes=max_bytes, data=data)
    return spectra_of(log)


def spectra_of(log: Log) -> list[Spectrum]:
    out = []
    if log.frames and log.foreground is not None:
        meta = {"frames": log.frames, "resets": log.resets, "timing_breaks": log.timing_breaks,
                "recalibrations": log.recalibrations, "out_of_order": log.out_of_order}
        real = (log.last_frame_end or 0) - (log.first_frame_start or 0)
        out.append(make_spectrum(log.path, "frames (their sum)", log.foreground, log.frame_live_s,
                                 real if real >= log.frame_live_s else None, calibration=log.calibration,
                                 serial=log.serial, kind="foreground", start_time=_iso(log.first_frame_start or 0),
                                 meta=meta))
    if log.last_record is not None:
        out.append(log.last_record)
    if not out:
        raise _err(log.path, "spectra", f"{log.spectrum_records} spectrum records give no frame and no spectrum "
                   "(a single record, or only resets and timing breaks)")
    return out
