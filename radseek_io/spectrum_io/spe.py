"""Ortec ASCII .spe (ORTEC software file structure manual)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .core import Spectrum, SpectrumFileError, _check_counts, _err, _float, _floats, _poly_cal, read_limited


def read_spe(path: str | Path, data: bytes | None = None) -> list[Spectrum]:
    """An Ortec ASCII .spe file."""
    data = read_limited(path) if data is None else data
    data = data[3:] if data.startswith(b"\xef\xbb\xbf") else data  # a UTF-8 byte-order mark
    try:
        lines = [ln.strip() for ln in data.decode("latin-1").splitlines()]
    except Exception as exc:  # pragma: no cover - latin-1 decodes any byte string
        raise SpectrumFileError(f"{path}: cannot decode ({exc})") from None
    sections: dict[str, list[str]] = {}
    key = None
    for ln in lines:
        if ln.startswith("$"):
            key = ln[1:].rstrip(":").strip().upper()
            sections[key] = []
        elif key is not None:
            sections[key].append(ln)
    if "DATA" not in sections:
        raise _err(path, "$DATA:", "section missing (not an Ortec .spe file?)")
    body = [ln for ln in sections["DATA"] if ln]
    if not body:
        raise _err(path, "$DATA:", "empty section")
    rng = body[0].split()
    if len(rng) != 2:
        raise _err(path, "$DATA:", f"first line must be 'first last' channel, got {body[0]!r}")
    first, last = (int(_float(path, "$DATA: channel range", t)) for t in rng)
    if first < 0 or last < first:
        raise _err(path, "$DATA:", f"bad channel range {first} {last}")
    values = []
    for i, ln in enumerate(body[1:]):
        values.extend(_floats(path, f"$DATA: line {i + 2}", ln))
    if len(values) != last - first + 1:
        raise _err(path, "$DATA:", f"range {first}..{last} needs {last - first + 1} counts, found {len(values)}")
    counts = _check_counts(path, "$DATA:", values)
    if first:
        counts = np.r_[np.zeros(first), counts]
    if "MEAS_TIM" not in sections or not sections["MEAS_TIM"]:
        raise _err(path, "$MEAS_TIM:", "section missing (live and real time)")
    times = _floats(path, "$MEAS_TIM:", sections["MEAS_TIM"][0])
    if len(times) < 1:
        raise _err(path, "$MEAS_TIM:", "needs 'live real' seconds")
    live, real = times[0], (times[1] if len(times) > 1 else None)
    if live <= 0:
        raise _err(path, "$MEAS_TIM:", f"live time must be > 0, got {live}")
    cal: tuple[float, ...] = (0.0, 1.0)
    if sections.get("MCA_CAL"):
        mc = [ln for ln in sections["MCA_CAL"] if ln]
        if len(mc) < 2:
            raise _err(path, "$MCA_CAL:", "needs the coefficient count and the coefficients")
        n = int(_float(path, "$MCA_CAL: count", mc[0]))
        coefs = [_float(path, "$MCA_CAL: coefficients", t) for t in mc[1].split()[:n]]
        if len(coefs) != n or n < 1:
            raise _err(path, "$MCA_CAL:", f"says {n} coefficients, found {len(coefs)}")
        cal = _poly_cal(path, "$MCA_CAL:", coefs, len(counts))
    elif sections.get("ENER_FIT"):
        cal = _poly_cal(path, "$ENER_FIT:", _floats(path, "$ENER_FIT:", sections["ENER_FIT"][0]), len(counts))
    title = " ".join(sections.get("SPEC_ID", [])).strip()
    date = " ".join(sections.get("DATE_MEA", [])).strip() or None
    return [Spectrum(counts, live, real, cal, None, date, title, "", "foreground", str(path))]


def write_spe(path: str | Path, sp: Spectrum) -> Path:
    """An Ortec ASCII .spe (used by the tests; polynomial calibration only)."""
    lines = ["$SPEC_ID:", sp.title or "radseek", "$DATE_MEA:", sp.start_time or "01/01/1970 00:00:00", "$MEAS_TIM:",
             f"{sp.livetime:.10g} {sp.realtime or sp.livetime:.10g}", "$DATA:", f"0 {sp.n_channels - 1}"]
    lines += [str(int(c)) for c in sp.counts]
    lines += ["$MCA_CAL:", str(len(sp.calibration)), " ".join(f"{c:.9g}" for c in sp.calibration) + " keV"]
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)
