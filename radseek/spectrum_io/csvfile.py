"""CSV spectra."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from .core import Spectrum, SpectrumFileError, _check_counts, _err, _float, _floats, _poly_cal


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


def read_csv(path: str | Path, data: bytes | None = None) -> list[Spectrum]:
    """A CSV spectrum (see the module docstring)."""
    data = Path(path).read_bytes() if data is None else data
    meta, rows = read_commented_csv(data.decode("utf-8-sig", errors="replace"))
    if not rows:
        raise _err(path, "rows", "no data rows")
    header = None
    if any(not _is_number(c) for c in rows[0]):
        header = [c.strip().lower() for c in rows[0]]
        rows = rows[1:]
    width = len(rows[0]) if rows else 0
    if width not in (1, 2):
        raise _err(path, "row 1", f"needs 1 (counts) or 2 (channel|energy_keV, counts) columns, got {width}")
    vals = []
    for i, r in enumerate(rows):
        if len(r) != width:
            raise _err(path, f"row {i + 1 + (header is not None)}", f"has {len(r)} columns, expected {width}")
        vals.append([_float(path, f"row {i + 1 + (header is not None)}", c) for c in r])
    arr = np.asarray(vals, dtype=float).reshape(len(vals), width)
    counts = _check_counts(path, "counts column", list(arr[:, -1]))
    if "live_time_s" not in meta:
        raise _err(path, "# live_time_s:", "comment line missing (live time in seconds)")
    live = _float(path, "# live_time_s:", meta["live_time_s"])
    real = _float(path, "# real_time_s:", meta["real_time_s"]) if "real_time_s" in meta else None
    cal: tuple[float, ...] = (0.0, 1.0)
    bounds = None
    if "calibration" in meta:
        cal = _poly_cal(path, "# calibration:", _floats(path, "# calibration:", meta["calibration"].replace(",", " ")),
                        len(counts))
    elif width == 2 and header is not None and header[0].startswith("energy"):
        lo = arr[:, 0]
        if len(lo) < 2 or np.any(np.diff(lo) <= 0):
            raise _err(path, f"column {header[0]!r}", "energies must be strictly ascending")
        bounds = np.r_[lo, 2 * lo[-1] - lo[-2]]
    try:
        return [Spectrum(counts, live, real, cal, bounds, meta.get("start_time"), meta.get("title", ""), "",
                         meta.get("kind", "foreground"), str(path))]
    except SpectrumFileError as exc:
        raise _err(path, "spectrum", str(exc).split(": ", 1)[-1]) from None


def _is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def write_csv(path: str | Path, sp: Spectrum) -> Path:
    lines = [f"# live_time_s: {sp.live_time_s:.9g}"]
    if sp.real_time_s:
        lines.append(f"# real_time_s: {sp.real_time_s:.9g}")
    lines += ["# calibration: " + " ".join(f"{c:.9g}" for c in sp.calibration), "channel,counts"]
    lines += [f"{i},{c:.9g}" for i, c in enumerate(sp.counts)]
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)
