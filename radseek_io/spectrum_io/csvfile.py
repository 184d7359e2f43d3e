"""CSV spectra."""

from __future__ import annotations

import csv
import io
import re
from pathlib import Path

import numpy as np

from .core import MAX_CHANNELS, Spectrum, _check_counts, _err, _float, _floats, _poly_cal, make_spectrum, read_limited


def read_commented_csv(text: str) -> tuple[dict[str, str], list[list[str]]]:
    """``# key: value`` comment lines (keys lower-cased) and the CSV rows of a text; blank lines skipped."""
    meta: dict[str, str] = {}
    rows: list[list[str]] = []
    for ln in text.splitlines():
        s = ln.strip()
        if not s:
            continue
        if s.startswith("#"):
            if ":" in s:
                k, v = s[1:].split(":", 1)
                meta[k.strip().lower()] = v.strip()
            continue
        rows.append(next(csv.reader(io.StringIO(s))))
    return meta, rows


_META_SPLIT = re.compile(r"\s*[:=,;\t]\s*")
LIVE_KEYS = {"livetime", "live", "lt"}
REAL_KEYS = {"realtime", "real", "rt", "measurementtime", "measuretime", "duration", "accumulationtime",
             "acquisitiontime", "elapsedtime"}
CAL_KEYS = {"calibration", "energycalibration", "calibrationcoefficients", "coefficients"}
CHANNEL_COLS = {"channel", "ch", "chan", "channelnumber", "channelno", "bin", "index"}
COUNT_COLS = {"counts", "count", "cnt", "countsperchannel", "value", "n", "data", "events", "pulses"}


def _norm(key: str) -> str:
    """A header or meta key reduced to letters, a trailing unit word dropped: 'Live Time (s)' -> 'livetime'."""
    k = re.sub(r"[^a-z]", "", key.lower())
    return re.sub(r"(seconds|secs|sec|s)$", "", k) if k not in ("counts", "pulses", "events") else k


def _column_kind(name: str) -> str | None:
    k = re.sub(r"[^a-z]", "", name.lower())
    if k in CHANNEL_COLS:
        return "channel"
    if k.startswith("energy") or k in ("kev", "e"):
        return "energy"
    if k in COUNT_COLS or k.startswith("counts"):
        return "counts"
    return None


def _delimiter(line: str) -> str:
    for d in ("\t", ";", ","):
        if d in line:
            return d
    return ","


def read_csv(path: str | Path, data: bytes | None = None, live_time_s: float | None = None) -> list[Spectrum]:
    """A CSV spectrum: one row per channel, columns ``channel``, ``energy`` (keV, lower channel edge) and
    ``counts`` in any order (named by a header row; without one: ``counts``, ``channel,counts`` (integral first
    column) or ``energy,counts``, or ``channel,energy,counts``); delimiter ``,``, ``;`` or tab. The channel
    column is honoured: rows are placed by channel number (sorted, gaps kept as zero counts; duplicate or absurd
    channel numbers refused). Live time from a ``# live_time_s: 300`` / ``# LiveTime, 300`` style line (``#``
    optional before the data; keys matched without case, spaces or units), else ``live_time_s`` (``--live-time``:
    the file's own figure is never replaced), else a real or measurement time (``MeasurementTime,532``) taken as
    the live time, else an error saying so. ``# calibration: c0 c1 c2`` gives the energy calibration; without it an
    energy column does (with a channel column: a polynomial of degree <= 2 fitted through it; without: its values
    are the edges)."""
    data = read_limited(path) if data is None else data
    text = data.decode("utf-8-sig", errors="replace")
    meta: dict[str, str] = {}
    header: list[str] | None = None
    rows: list[tuple[int, list[str]]] = []
    delim = None
    for ln_no, ln in enumerate(text.splitlines(), 1):
        s = ln.strip()
        if not s:
            continue
        if s.startswith("#"):
            parts = _META_SPLIT.split(s.lstrip("#").strip(), maxsplit=1)
            if len(parts) == 2 and parts[0]:
                meta[_norm(parts[0])] = parts[1].strip()
            continue
        delim = delim or _delimiter(s)
        cells = [c.strip() for c in next(csv.reader(io.StringIO(s), delimiter=delim))]
        if not rows and cells and not _is_number(cells[0]):
            k = _norm(cells[0])
            if len(cells) >= 2 and _is_number(cells[1]) and (k in LIVE_KEYS | REAL_KEYS | CAL_KEYS):
                meta[k] = " ".join(cells[1:])
                delim = None  # the data rows may use another delimiter than a 'key,value' line
                continue
            if header is None and all(not _is_number(c) for c in cells):
                header = cells
                continue
        rows.append((ln_no, cells))
    if not rows:
        raise _err(path, "rows", "no data rows")
    width = len(rows[0][1])
    for ln_no, r in rows:
        if len(r) != width:
            raise _err(path, f"line {ln_no}", f"has {len(r)} columns, expected {width}")
    arr = np.array([[_float(path, f"line {ln_no} column {j + 1}", c) for j, c in enumerate(r)] for ln_no, r in rows],
                   dtype=float).reshape(len(rows), width)
    lines = [ln_no for ln_no, _ in rows]
    cols: dict[str, int] = {}
    if header is not None:
        if len(header) != width:
            raise _err(path, "header", f"names {len(header)} columns, the rows have {width}")
        for j, name in enumerate(header):
            kind = _column_kind(name)
            if kind is not None and kind not in cols:
                cols[kind] = j
        if "counts" not in cols:
            free = [j for j in range(width) if j not in cols.values()]
            if len(free) != 1:
                raise _err(path, "header", f"no counts column among {header} (name one 'counts')")
            cols["counts"] = free[0]
    elif width == 1:
        cols = {"counts": 0}
    elif width == 2:
        first = arr[:, 0]
        cols = {"channel" if np.all(first == np.round(first)) else "energy": 0, "counts": 1}
    elif width == 3:
        cols = {"channel": 0, "energy": 1, "counts": 2}
    else:
        raise _err(path, f"line {lines[0]}", f"{width} columns without a header row (name them: channel, energy, "
                   "counts)")
    counts_in = arr[:, cols["counts"]]
    _check_counts(path, "counts column", counts_in)  # names the first bad value's position
    bounds = None
    cal: tuple[float, ...] = (0.0, 1.0)
    if "channel" in cols:
        ch = arr[:, cols["channel"]]
        for k, c in enumerate(ch):
            if c != round(c) or not 0 <= c < MAX_CHANNELS:
                raise _err(path, f"line {lines[k]} channel", f"{c:.15g} is not a channel number 0..{MAX_CHANNELS - 1}")
        chi = ch.astype(int)
        seen: dict[int, int] = {}
        for k, c in enumerate(chi):
            if c in seen:
                raise _err(path, f"line {lines[k]} channel", f"{c} already given on line {seen[c]}")
            seen[int(c)] = lines[k]
        counts = np.zeros(int(chi.max()) + 1)
        counts[chi] = counts_in
        if "energy" in cols and "calibration" not in meta:
            e = arr[:, cols["energy"]]
            deg = min(2, len(e) - 1)
            if deg < 1:
                raise _err(path, "energy column", "one row cannot calibrate (add '# calibration: c0 c1 c2')")
            coef = np.polynomial.polynomial.polyfit(chi.astype(float), e, deg)
            resid = np.abs(np.polynomial.polynomial.polyval(chi, coef) - e).max()
            if not resid <= max(0.5, 1e-3 * float(np.ptp(e))):
                raise _err(path, "energy column", f"not a polynomial of degree <= 2 in the channel (off by "
                           f"{resid:.3g} keV): add '# calibration: c0 c1 c2'")
            cal = _poly_cal(path, "energy column (fitted calibration)", tuple(float(c) for c in coef), len(counts))
    elif "energy" in cols:
        e = arr[:, cols["energy"]]
        order = np.argsort(e, kind="stable")
        e, counts = e[order], counts_in[order]
        dup = np.flatnonzero(np.diff(e) == 0)
        if len(e) < 2 or len(dup):
            where = f"line {lines[order[dup[0] + 1]]}" if len(dup) else "energy column"
            raise _err(path, where, "energies must be distinct (two or more rows)")
        bounds = np.r_[e, 2 * e[-1] - e[-2]]
    else:
        counts = counts_in
    if "calibration" in meta:
        cal = _poly_cal(path, "# calibration:", _calibration_coefficients(path, meta["calibration"]), len(counts))
        bounds = None
    live, real = _times(path, meta, live_time_s)
    return [make_spectrum(path, "spectrum", counts, live, real, calibration=cal, bin_edges_kev=bounds,
                          start_time=meta.get("starttime"), title=meta.get("title") or meta.get("spectrumname", ""),
                          serial=meta.get("serialnumber") or meta.get("serial", ""),
                          kind=meta.get("kind", "foreground"))]


_TERM = re.compile(r"\s*([+-]?)\s*(\d+(?:\.\d*)?(?:[eE][+-]?\d+)?|\.\d+(?:[eE][+-]?\d+)?)"
                   r"(?:\s*\*\s*([A-Za-z_]\w*)(?:\s*(?:\^|\*\*)\s*(\d+))?)?")


def _calibration_coefficients(path, text: str) -> list[float]:
    """Coefficients c0 c1 c2 ... of a calibration line: plain numbers (``0.5 2.4 3e-4``, comma or space separated)
    or a polynomial in the channel as tools write it, ``E_keV = 5.15 + 2.43*c + 0.000375*c^2`` (any variable name,
    ``^`` or ``**``, terms in any order)."""
    if "=" not in text and "*" not in text:
        return _floats(path, "# calibration:", text.replace(",", " "))
    rhs = text.split("=", 1)[1] if "=" in text else text
    coefs: dict[int, float] = {}
    pos, var = 0, None
    while pos < len(rhs.rstrip()):
        m = _TERM.match(rhs, pos)
        if m is None or m.end() == pos:
            raise _err(path, "# calibration:", f"not a polynomial in the channel at {rhs[pos:].strip()!r} "
                       "(write it as 'E = c0 + c1*ch + c2*ch^2' or 'c0 c1 c2')")
        sign, num, name, power = m.groups()
        if name is not None:
            if var is not None and name != var:
                raise _err(path, "# calibration:", f"two variables, {var!r} and {name!r}, in {rhs.strip()!r}")
            var = name
        k = 0 if name is None else int(power or 1)
        if k in coefs:
            raise _err(path, "# calibration:", f"the power {k} of the channel appears twice in {rhs.strip()!r}")
        coefs[k] = float(sign + num)
        pos = m.end()
    if not coefs:
        raise _err(path, "# calibration:", f"no coefficients in {text.strip()!r}")
    return [coefs.get(k, 0.0) for k in range(max(coefs) + 1)]


def _times(path, meta: dict[str, str], live_time_s: float | None) -> tuple[float, float | None]:
    real = None
    for k in REAL_KEYS:
        if k in meta:
            real = _float(path, f"{k} (real time)", meta[k].split()[0] if meta[k].split() else "")
            break
    for k in LIVE_KEYS:
        if k in meta:
            return _float(path, f"{k} (live time)", meta[k].split()[0] if meta[k].split() else ""), real
    if live_time_s is not None:
        return float(live_time_s), real
    if real is not None:
        return real, None  # no dead time recorded: the measurement time is the live time
    raise _err(path, "live time", "not in the file: add a '# live_time_s: 300' line, or give --live-time SECONDS")


def _is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def write_csv(path: str | Path, sp: Spectrum) -> Path:
    lines = [f"# live_time_s: {sp.livetime:.9g}"]
    if sp.realtime:
        lines.append(f"# real_time_s: {sp.realtime:.9g}")
    lines += ["# calibration: " + " ".join(f"{c:.9g}" for c in sp.calibration), "channel,counts"]
    lines += [f"{i},{c:.9g}" for i, c in enumerate(sp.counts)]
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)
