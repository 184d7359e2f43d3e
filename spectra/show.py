"""``radseek spectra show FILE [--json] [--live-time S]``: what the readers made of a spectrum file.

``spectra``: each spectrum read (``kind`` foreground / background / accumulated), with ``live_time_s``,
``real_time_s``, ``total_counts``, ``channels``, ``calibration_keV`` (E(i) = c0 + c1 i + c2 i^2, lower channel
edges), ``start_time``, ``serial``; for spectrograms and logs ``rows`` (time rows or frames: count, first start,
last end, live time); for logs with GNSS ``gnss_fixes`` (count, first, last). The JSON is strict: a value that is
not a finite number is written ``null``, never ``NaN``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from radseek_io.spectrum_io import Spectrum, format_of, read_spectra
from radseek_io.spectrum_io.ndjson import _iso, scan, spectra_of


def strict(obj: Any) -> Any:
    """``obj`` with numpy values as Python ones and every non-finite float as None (strict JSON)."""
    if isinstance(obj, dict):
        return {str(k): strict(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [strict(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [strict(v) for v in obj.tolist()]
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    return obj


def dumps(obj: Any) -> str:
    return json.dumps(strict(obj), indent=2, allow_nan=False)


def _spectrum(sp: Spectrum) -> dict[str, Any]:
    return {"kind": sp.kind, "live_time_s": sp.livetime, "real_time_s": sp.realtime,
            "total_counts": float(sp.counts.sum()), "channels": sp.n_channels,
            "calibration_keV": list(sp.calibration) if sp.bin_edges_kev is None else None,
            "boundaries_keV": [float(sp.bin_edges_kev[0]), float(sp.bin_edges_kev[-1])]
            if sp.bin_edges_kev is not None else None,
            "start_time": sp.start_time or None, "serial": sp.serial or None, "title": sp.title or None}


def describe(path: str | Path, live_time_s: float | None = None, max_bytes: int | None = None) -> dict[str, Any]:
    """The description printed by ``show`` (raises SpectrumFileError for a file that does not read)."""
    fmt = format_of(path, None, max_bytes)
    out: dict[str, Any] = {"file": str(path), "format": fmt}
    if fmt == "ndjson":
        log = scan(path, max_bytes=max_bytes)
        out["spectra"] = [_spectrum(s) for s in spectra_of(log)] if log.spectrum_records else []
        out["rows"] = {"count": log.frames, "what": "frames: differences of consecutive cumulative spectra",
                       "first_start": _iso(log.first_frame_start) if log.first_frame_start else None,
                       "last_end": _iso(log.last_frame_end) if log.last_frame_end else None,
                       "live_time_s": log.frame_live_s, "spectrum_records": log.spectrum_records,
                       "device_resets": log.resets, "timing_breaks": log.timing_breaks,
                       "recalibrations": log.recalibrations, "out_of_order_skipped": log.out_of_order}
        g = log.gnss

        def fix(f):
            return {"time": _iso(f.t), "lat": f.lat, "lon": f.lon, "alt_m": f.alt, "sigma_h_m": f.sigma_h}

        out["gnss_fixes"] = {"count": len(g), "without_fix": log.gnss_without_fix,
                             "first": fix(g[0]) if g else None, "last": fix(g[-1]) if g else None}
        out["device_records"] = dict(log.device_records)
        if log.other_serials:
            out["other_devices_skipped"] = dict(log.other_serials)
        out["notes"] = log.notes
        return out
    spectra = read_spectra(path, live_time_s=live_time_s, max_bytes=max_bytes)
    out["spectra"] = [_spectrum(s) for s in spectra]
    if fmt == "rcspg":
        m = spectra[0].meta
        out["rows"] = {"count": m["rows"], "what": "time rows (differential spectra)",
                       "first_start": m["first_row_start"], "last_end": m["last_row_end"],
                       "live_time_s": spectra[0].livetime, "header_accumulation_time_s":
                       m["header_accumulation_time_s"]}
    return out


def _fmt(v: Any, spec: str = ".6g") -> str:
    return "-" if v is None else format(v, spec) if isinstance(v, (int, float)) else str(v)


def human(d: dict[str, Any]) -> str:
    lines = [f"{d['file']}: {d['format']}"]
    if d.get("spectra"):
        lines.append(f"  {'kind':<12} {'live s':>11} {'real s':>11} {'counts':>13} {'ch':>5}  calibration keV"
                     f"{'':<24} start                     serial")
        for s in d["spectra"]:
            cal = (" ".join(_fmt(c, ".5g") for c in s["calibration_keV"]) if s["calibration_keV"] is not None
                   else f"edges {_fmt(s['boundaries_keV'][0])}..{_fmt(s['boundaries_keV'][1])}")
            lines.append(f"  {s['kind']:<12} {_fmt(s['live_time_s'], '.10g'):>11} {_fmt(s['real_time_s'], '.10g'):>11} "
                         f"{_fmt(s['total_counts'], '.13g'):>13} {s['channels']:>5}  {cal:<39} "
                         f"{_fmt(s['start_time']):<25} {_fmt(s['serial'])}")
    r = d.get("rows")
    if r:
        lines.append(f"  rows: {r['count']} {r['what']}, {_fmt(r['first_start'])} .. {_fmt(r['last_end'])}, "
                     f"live {_fmt(r['live_time_s'], '.8g')} s")
        extra = [f"{k.replace('_', ' ')} {r[k]}" for k in ("device_resets", "timing_breaks", "recalibrations",
                                                            "out_of_order_skipped") if r.get(k)]
        if extra:
            lines.append("  (" + ", ".join(extra) + ": no frame across them)")
    g = d.get("gnss_fixes")
    if g is not None:
        if g["count"]:
            lines.append(f"  gnss fixes: {g['count']}, {g['first']['time']} .. {g['last']['time']}, first at "
                         f"{g['first']['lat']:.6f}, {g['first']['lon']:.6f}" + (f" ({g['without_fix']} without a fix)"
                                                                               if g["without_fix"] else ""))
        else:
            lines.append("  gnss fixes: none")
    if d.get("device_records"):
        lines.append("  device records: " + ", ".join(f"{k} {v}" for k, v in sorted(d["device_records"].items())))
    for n in d.get("notes", []):
        lines.append(f"  note: {n}")
    return "\n".join(lines)
