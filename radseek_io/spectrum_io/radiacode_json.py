"""RadiaCode spectra as JSON documents (one spectrum, or a foreground and background pair).

Schemas read (radiacode-tools, github.com/ckuethe/radiacode-tools, MIT):

- ``RcSpectrum.as_dict()`` / ``from_dict`` (``radiacode_tools/rc_files.py``): ``{"fg": layer, "bg": layer or
  null, "note": str}``, a layer being ``spectrum_name``, ``device_model``, ``serial_number``, ``calibration``
  (``[a0, a1, a2]`` or ``{"a0", "a1", "a2"}``), ``timestamp`` (ISO), ``duration`` (s), ``channels``,
  ``counts``, ``comment``;
- one spectrum record of an rcmultispg log (:mod:`.ndjson`): ``timestamp``, ``serial_number``, ``duration``,
  ``calibration``, ``counts`` (the device's cumulative spectrum: kind ``accumulated``), or its ``SpecData``
  form.

The RadiaCode phone apps (Android, iOS) export XML (:mod:`.radiacode_xml`); no public JSON export of theirs was
found to check a reader against (see docs/real-spectra.md), so none is claimed here.
"""

from __future__ import annotations

import math
from pathlib import Path

from .core import MAX_TIME_S, Spectrum, _err, _poly_cal, make_spectrum
from .ndjson import _counts, _iso, _spectrum_fields, read_json_object


def _cal(path, where: str, cal, n: int) -> tuple[float, ...]:
    if isinstance(cal, dict):
        cal = [cal.get(k) for k in ("a0", "a1", "a2")]
    if not isinstance(cal, list) or not 2 <= len(cal) <= 4 or not all(
            isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in cal):
        raise _err(path, f"{where} calibration", f"must be [a0, a1, a2] numbers, got {cal!r}")
    return _poly_cal(path, f"{where} calibration", [float(c) for c in cal], n)


def _layer(path, where: str, d, kind: str) -> Spectrum:
    if not isinstance(d, dict):
        raise _err(path, where, "must be an object (a spectrum layer)")
    counts = _counts(path, where, d.get("counts"))
    ch = d.get("channels")
    if ch is not None and ch != len(counts):
        raise _err(path, f"{where} channels", f"says {ch!r} but counts has {len(counts)}")
    dur = d.get("duration")
    if isinstance(dur, bool) or not isinstance(dur, (int, float)) or not (math.isfinite(dur)
                                                                          and 0 < dur <= MAX_TIME_S):
        raise _err(path, f"{where} duration", f"must be > 0 and <= {MAX_TIME_S:g} s, got {dur!r}")
    ts = d.get("timestamp")
    return make_spectrum(path, where, counts, float(dur), None, calibration=_cal(path, where, d.get("calibration"),
                                                                                  len(counts)),
                         start_time=ts if isinstance(ts, str) else None,
                         title=str(d.get("spectrum_name", "") or ""), serial=str(d.get("serial_number", "") or ""),
                         kind=kind, meta={"device_model": str(d.get("device_model", "") or "")})


def read_radiacode_json(path: str | Path, data: bytes | None = None) -> list[Spectrum]:
    """The spectra of a RadiaCode JSON document (see the module docstring)."""
    doc = read_json_object(path, data)
    if "fg" in doc:
        out = [_layer(path, "fg", doc["fg"], "foreground")]
        if doc.get("bg") is not None:
            out.append(_layer(path, "bg", doc["bg"], "background"))
        return out
    fields = _spectrum_fields(path, "record", doc)
    if fields is None:
        raise _err(path, "JSON", "neither an RcSpectrum document ('fg', 'bg') nor a spectrum record "
                   "('timestamp', 'duration', 'calibration', 'counts')")
    t, sn, dur, cal, counts_raw = fields
    counts = _counts(path, "record", counts_raw)
    if dur <= 0:
        raise _err(path, "record field 'duration'", "must be > 0")
    return [make_spectrum(path, "record", counts, dur, None, calibration=_cal(path, "record", cal, len(counts)),
                          start_time=_iso(t - dur), serial=sn, kind="accumulated")]
