"""Gamma spectrum files: read N42 (ANSI N42.42-2011), RadiaCode XML, Ortec .spe / .chn and CSV; write N42.

Every reader returns :class:`Spectrum` objects (counts per channel, live and real time, energy calibration); every
error is a :class:`SpectrumFileError` naming the file and the element, section or byte offset that is wrong.

Which library: ``becquerel`` 0.7 (PyPI) was checked on Python 3.11 here. It reads Ortec .spe, Canberra .cnf, .spc
and IEC 1455, but not N42, RadiaCode XML, .chn or CSV; it pulls numba, pandas, lmfit and black, prints a line per
file read and rejects an .spe without ``$DATE_MEA``. So the readers here are small and validated, and
``tests/test_spectrum_files.py`` checks the .spe reader against becquerel and the N42 writer against SpecUtils
(``sandiaspecutils``, the library InterSpec is built on) when those are installed.

Energy calibration convention (the one of N42 and SpecUtils): the lower edge of channel i is
E(i) = c0 + c1 i + c2 i^2 keV, so channel i spans [E(i), E(i + 1)). All-zero coefficients (an uncalibrated
MCA) mean none (channel numbers); a calibration whose edges do not rise over the channels is an error. Files
with explicit boundaries (N42 ``EnergyBoundaryValues``, a CSV with an energy column) keep them.

Formats:

- **N42.42-2011**: ``RadMeasurement`` / ``Spectrum`` / ``ChannelData`` (``compressionCode`` or ``Compression``
  None or CountedZeroes), ``LiveTimeDuration`` / ``RealTimeDuration`` as xs:duration (``PT300S``; a bare
  number of seconds is taken too), the calibration referenced by ``energyCalibrationReference``
  (``CoefficientValues``, with deviation pairs applied as SpecUtils does, or ``EnergyBoundaryValues``);
  ``MeasurementClassCode`` tells foreground from background. Prefixes InterSpec leaves undeclared are bound.
- **N42.42-2006** (``N42InstrumentData``): ``Spectrum`` / ``LiveTime`` / ``RealTime`` / ``Calibration``
  (``Polynomial`` or ``FullRangeFraction``, inline or by ``CalibrationIDs``), ``SourceType`` for the kind.
- **RadiaCode XML** (the app's export, ``ResultDataFile`` / ``EnergySpectrum``): ``Spectrum/DataPoint``,
  ``MeasurementTime`` (s; the real time when a non-zero ``LiveTime`` is given, as AtomSpectra and BecqMoni
  write), ``EnergyCalibration/Coefficients`` (as many as ``PolynomialOrder`` + 1); the optional
  ``BackgroundEnergySpectrum`` is read as a second spectrum.
- **Ortec .spe** (ASCII, ORTEC software file structure manual): ``$MEAS_TIM:`` live real, ``$DATA:`` first last,
  ``$MCA_CAL:`` or ``$ENER_FIT:``, ``$DATE_MEA:``, ``$SPEC_ID:``.
- **Ortec .chn** (binary, little endian): 32-byte header (int16 -1, MCA, segment, 2-char seconds, int32 real
  and live time in 20 ms ticks, 8-char date DDMMMYY*, 4-char time HHMM, int16 first channel, int16 channel
  count), int32 counts, then an optional trailer (int16 -101 or -102, int16, float32 energy zero, slope and,
  for -102, quadratic).
- **CSV**: one row per channel, ``counts`` or ``channel,counts`` or ``energy_keV,counts`` (lower channel
  edge); ``# live_time_s: 300``, ``# real_time_s: ...`` and ``# calibration: c0 c1 c2`` comment lines.
"""

from __future__ import annotations

import csv
import io
import math
import re
import struct
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

N42_NS = "http://physics.nist.gov/N42/2011/N42"
SUFFIXES = {".n42": "n42", ".xml": "xml", ".spe": "spe", ".chn": "chn", ".csv": "csv", ".txt": "csv"}


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
        c = np.asarray(self.counts, dtype=float)
        if c.ndim != 1 or len(c) == 0:
            raise SpectrumFileError(f"{self.source or '<spectrum>'}: counts must be a non-empty 1-D array")
        if not np.all(np.isfinite(c)) or np.any(c < 0):
            raise SpectrumFileError(f"{self.source or '<spectrum>'}: counts must be finite and >= 0")
        if not (math.isfinite(self.live_time_s) and self.live_time_s > 0):
            raise SpectrumFileError(f"{self.source or '<spectrum>'}: live time must be > 0, got {self.live_time_s}")
        object.__setattr__(self, "counts", c)
        if self.boundaries_keV is not None:
            b = np.asarray(self.boundaries_keV, dtype=float)
            if b.shape != (len(c) + 1,) or np.any(np.diff(b) <= 0):
                raise SpectrumFileError(f"{self.source or '<spectrum>'}: {len(c) + 1} ascending channel boundaries "
                                        f"needed, got {b.shape[0]}")
            object.__setattr__(self, "boundaries_keV", b)

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


def _check_counts(path: str | Path, where: str, values: list[float]) -> np.ndarray:
    a = np.asarray(values, dtype=float)
    if len(a) == 0:
        raise _err(path, where, "no channel data")
    if np.any(a < 0) or not np.all(np.isfinite(a)):
        raise _err(path, where, "counts must be finite and >= 0")
    return a


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


# ------------------------------------------------------------------------------------------------ N42


def _n42_counts(path: str | Path, where: str, el: ET.Element) -> np.ndarray:
    """``ChannelData`` counts. The compression is ``compressionCode`` (N42-2011) or ``Compression`` (N42-2006,
    and what Radiation Solutions' AVID writes in 2011 files), ``CountedZeroes`` (one file writer spells it
    ``CountedZeros``) or ``None``; values may be separated by commas; 2006 files may wrap them in ``<Data>``."""
    data = _child(el, "Data")
    text = data.text if data is not None and (data.text or "").strip() else el.text
    values = _floats(path, where, (text or "").replace(",", " "))
    code = "None"
    for k, v in el.attrib.items():
        if _local(k).lower() in ("compressioncode", "compression"):
            code = v.strip() or "None"
    if code.lower() in ("countedzeroes", "countedzeros"):
        out: list[float] = []
        i = 0
        while i < len(values):
            if values[i] == 0:
                if i + 1 >= len(values):
                    raise _err(path, where, "CountedZeroes: a zero without its count at the end")
                n = values[i + 1]
                if n != int(n) or n < 0 or n > 10_000_000:
                    raise _err(path, where, f"CountedZeroes: bad zero count {n}")
                out.extend([0.0] * int(n))
                i += 2
            else:
                out.append(values[i])
                i += 1
        values = out
    elif code.lower() != "none":
        raise _err(path, where, f"unknown compressionCode {code!r} (None or CountedZeroes)")
    return _check_counts(path, where, values)


def read_n42(path: str | Path, data: bytes | None = None) -> list[Spectrum]:
    """Every spectrum of an N42.42-2011 file (or an N42.42-2006 one, :func:`read_n42_2006`), in file order
    (``kind`` from ``MeasurementClassCode``, ``meta["detector"]`` the ``radDetectorInformationReference``: a
    multi-detector instrument gives one spectrum per detector and measurement)."""
    data = Path(path).read_bytes() if data is None else data
    root = _parse_xml(path, data)
    if _local(root.tag) == "N42InstrumentData":
        return _read_n42_2006(path, root)
    if _local(root.tag) != "RadInstrumentData":
        raise _err(path, f"<{_local(root.tag)}>", "root element must be RadInstrumentData (N42.42-2011) or "
                   "N42InstrumentData (N42.42-2006)")
    cals: dict[str, tuple[str, list[float]]] = {}
    devs: dict[str, tuple[list[float], list[float]]] = {}
    for i, ec in enumerate(_children(root, "EnergyCalibration")):
        where = f"EnergyCalibration[{i}]"
        coef, bounds = _child(ec, "CoefficientValues"), _child(ec, "EnergyBoundaryValues")
        if coef is not None:
            cals[ec.get("id", "")] = ("coef", _floats(path, where + "/CoefficientValues", coef.text))
            ev, dv = _child(ec, "EnergyValues"), _child(ec, "EnergyDeviationValues")
            if ev is not None and dv is not None:
                devs[ec.get("id", "")] = (_floats(path, where + "/EnergyValues", ev.text),
                                          _floats(path, where + "/EnergyDeviationValues", dv.text))
        elif bounds is not None:
            cals[ec.get("id", "")] = ("bounds", _floats(path, where + "/EnergyBoundaryValues", bounds.text))
        else:
            cals[ec.get("id", "")] = ("none", [])
    serial = ""
    rii = _child(root, "RadInstrumentInformation")
    if rii is not None and _child(rii, "RadInstrumentIdentifier") is not None:
        serial = (_child(rii, "RadInstrumentIdentifier").text or "").strip()  # type: ignore[union-attr]
    out: list[Spectrum] = []
    for m, meas in enumerate(_children(root, "RadMeasurement")):
        mwhere = f"RadMeasurement[{m}]" + (f" id={meas.get('id')!r}" if meas.get("id") else "")
        cls = _child(meas, "MeasurementClassCode")
        kind = (cls.text or "").strip().lower() if cls is not None else "foreground"
        start = _child(meas, "StartDateTime")
        real_el = _child(meas, "RealTimeDuration")
        real = parse_duration(path, mwhere + "/RealTimeDuration", real_el.text) if real_el is not None else None
        remark = _child(meas, "Remark")
        for s, sp in enumerate(_children(meas, "Spectrum")):
            where = f"{mwhere}/Spectrum[{s}]"
            cd = _child(sp, "ChannelData")
            if cd is None:
                raise _err(path, where, "missing ChannelData")
            counts = _n42_counts(path, where + "/ChannelData", cd)
            live = _live_time(path, where, sp, "LiveTimeDuration", real, "RealTimeDuration")
            ref = sp.get("energyCalibrationReference")
            cal: tuple[float, ...] = (0.0, 1.0)
            bounds = None
            if ref is not None:
                if ref not in cals:
                    raise _err(path, where, f"energyCalibrationReference {ref!r} names no EnergyCalibration")
                how, vals = cals[ref]
                if how == "none":
                    raise _err(path, f"EnergyCalibration id={ref!r}", "neither CoefficientValues nor "
                               "EnergyBoundaryValues")
                if how == "coef":
                    if not vals:
                        raise _err(path, f"EnergyCalibration id={ref!r}", "empty CoefficientValues")
                    cal = _poly_cal(path, f"EnergyCalibration id={ref!r}/CoefficientValues", vals, len(counts))
                    if ref in devs:
                        bounds = _deviation_pairs(path, f"EnergyCalibration id={ref!r}/EnergyDeviationValues",
                                                  cal, len(counts), *devs[ref])
                else:
                    if len(vals) != len(counts) + 1:
                        raise _err(path, f"EnergyCalibration id={ref!r}/EnergyBoundaryValues",
                                   f"{len(vals)} boundaries for {len(counts)} channels (need n + 1)")
                    bounds = np.asarray(vals)
            try:
                out.append(Spectrum(counts, live, real, cal, bounds, (start.text or "").strip() if start is not None
                                    else None, (remark.text or "").strip() if remark is not None else "", serial,
                                    kind, str(path), {"measurement_id": meas.get("id", ""),
                                                     "detector": sp.get("radDetectorInformationReference", "")}))
            except SpectrumFileError as exc:
                raise _err(path, where, str(exc).split(": ", 1)[-1]) from None
    if not out:
        raise _err(path, "RadInstrumentData", "no RadMeasurement/Spectrum with ChannelData")
    return out


def _live_time(path: str | Path, where: str, sp: ET.Element, tag: str, real: float | None, real_tag: str) -> float:
    """The spectrum's live time ``tag`` (xs:duration); without one, its real time (no dead time recorded)."""
    el = _child(sp, tag)
    if el is not None:
        return parse_duration(path, f"{where}/{tag}", el.text)
    if real is not None:
        return real
    raise _err(path, where, f"missing {tag} (and no {real_tag})")


def _deviation_pairs(path: str | Path, where: str, cal: tuple[float, ...], n: int, energies: list[float],
                     deviations: list[float]) -> np.ndarray | None:
    """Channel edges of a polynomial calibration with deviation pairs (N42-2011 ``EnergyValues`` /
    ``EnergyDeviationValues``, GADRAS' non-linearity correction), as SpecUtils applies them: the correction at
    polynomial energy E is a cubic spline through (E_i - d_i, d_i), second derivative 0 at the first pair, slope
    0 at the last, constant beyond them. All-zero deviations change nothing (``None``)."""
    if len(energies) != len(deviations):
        raise _err(path, where, f"{len(deviations)} deviations for {len(energies)} EnergyValues")
    if not any(deviations):
        return None
    from scipy.interpolate import CubicSpline

    x = np.asarray(energies, dtype=float) - np.asarray(deviations, dtype=float)
    if len(x) < 2 or np.any(np.diff(x) <= 0):
        raise _err(path, where, "needs two or more pairs with ascending energies")
    spline = CubicSpline(x, deviations, bc_type=((2, 0.0), (1, 0.0)))
    e = polynomial_edges(cal, n)
    e = e + np.where(e < x[0], deviations[0], np.where(e > x[-1], deviations[-1], spline(e)))
    if not _rising(e):
        raise _err(path, where, "the corrected channel energies do not rise")
    return e


_SOURCE_KIND = {"background": "background", "calibration": "calibration", "intrinsic": "intrinsicactivity"}


def _read_n42_2006(path: str | Path, root: ET.Element) -> list[Spectrum]:
    """Every gamma spectrum of an N42.42-2006 file (``N42InstrumentData``), in file order: any ``Spectrum``
    with ``ChannelData`` (under ``Measurement`` directly, or ``DetectorData`` / ``DetectorMeasurement`` /
    ``SpectrumMeasurement``), ``LiveTime`` / ``RealTime`` as xs:duration (``RealTime`` or the enclosing
    ``SampleRealTime`` stands in for a missing ``LiveTime``), the energy ``Calibration`` inside the spectrum or
    named by its ``CalibrationIDs`` (``Equation`` ``Polynomial`` or ``FullRangeFraction``), ``SourceType`` for
    the kind. Spectra of a ``DetectorType="Neutron"`` measurement are skipped."""
    cal_ids = {c.get("ID"): c for c in root.iter() if _local(c.tag) == "Calibration" and c.get("ID")}
    out: list[Spectrum] = []

    def walk(el: ET.Element, ctx: dict) -> None:
        for ch in el:
            name = _local(ch.tag)
            if name == "Spectrum" and _child(ch, "ChannelData") is not None:
                if (ctx.get("dtype") or ch.get("DetectorType") or "").lower() != "neutron":
                    out.append(_n42_2006_spectrum(path, ch, ctx, cal_ids, len(out)))
                continue
            if name in ("Calibration", "ChannelData"):
                continue
            sub = dict(ctx)
            for tag, key in (("StartTime", "start"), ("SampleRealTime", "real")):
                e = _child(ch, tag)
                if e is not None and (e.text or "").strip():
                    sub[key] = (e.text or "").strip()
            for att, key in (("DetectorType", "dtype"), ("Detector", "detector")):
                if ch.get(att):
                    sub[key] = ch.get(att)
            walk(ch, sub)

    walk(root, {})
    if not out:
        raise _err(path, "N42InstrumentData", "no gamma Spectrum with ChannelData")
    return out


def _n42_2006_spectrum(path: str | Path, sp: ET.Element, ctx: dict, cal_ids: dict, i: int) -> Spectrum:
    det = sp.get("Detector") or sp.get("Sensor") or ctx.get("detector", "")
    where = f"Spectrum[{i}]" + (f" Detector={det!r}" if det else "")
    counts = _n42_counts(path, where + "/ChannelData", _child(sp, "ChannelData"))  # type: ignore[arg-type]
    rt = _child(sp, "RealTime")
    real = parse_duration(path, where + "/RealTime", rt.text) if rt is not None else (
        parse_duration(path, "SampleRealTime", ctx["real"]) if "real" in ctx else None)
    live = _live_time(path, where, sp, "LiveTime", real, "RealTime")
    cals = [c for c in _children(sp, "Calibration") if (c.get("Type") or "Energy").lower() == "energy"]
    for ref in (sp.get("CalibrationIDs") or "").split():
        if ref not in cal_ids:
            raise _err(path, where, f"CalibrationIDs {ref!r} names no Calibration")
        if (cal_ids[ref].get("Type") or "Energy").lower() == "energy":
            cals.append(cal_ids[ref])
    cal: tuple[float, ...] = (0.0, 1.0)
    bounds = None
    if cals:
        cal, bounds = _n42_2006_cal(path, where + "/Calibration", cals[0], len(counts))
    src = _child(sp, "SourceType")
    kind = _SOURCE_KIND.get((src.text or "").strip().lower(), "foreground") if src is not None else "foreground"
    try:
        return Spectrum(counts, live, real, cal, bounds, ctx.get("start"), "", "", kind, str(path),
                        {"detector": det, "sample": sp.get("SampleNumber", "")})
    except SpectrumFileError as exc:
        raise _err(path, where, str(exc).split(": ", 1)[-1]) from None


def _n42_2006_cal(path: str | Path, where: str, el: ET.Element, n: int) -> tuple[tuple[float, ...], np.ndarray | None]:
    eq = _child(el, "Equation")
    coef = _child(eq, "Coefficients") if eq is not None else None
    if coef is None:
        raise _err(path, where, "energy Calibration without Equation/Coefficients")
    vals = _floats(path, where + "/Equation/Coefficients", (coef.text or "").replace(",", " "))
    unit = (el.get("EnergyUnits") or "keV").strip().lower()
    if unit not in ("kev", "mev", "ev"):
        raise _err(path, where, f"EnergyUnits {el.get('EnergyUnits')!r} (keV, MeV or eV)")
    vals = [v * {"kev": 1.0, "mev": 1000.0, "ev": 0.001}[unit] for v in vals]
    model = (eq.get("Model") or "Polynomial").strip().lower()  # type: ignore[union-attr]
    if model == "polynomial":
        return _poly_cal(path, where + "/Equation/Coefficients", vals, n), None
    if model == "fullrangefraction":
        # E(x) = c0 + c1 x + c2 x^2 + c3 x^3 + c4 / (1 + 60 x), x = channel / n (SpecUtils, GADRAS)
        c = (vals + [0.0] * 5)[:5]
        x = np.arange(n + 1, dtype=float) / n
        e = c[0] + c[1] * x + c[2] * x**2 + c[3] * x**3 + c[4] / (1 + 60 * x)
        if not _rising(e):
            raise _err(path, where, f"FullRangeFraction calibration {tuple(vals)} does not rise over the channels")
        return (0.0, 1.0), e
    raise _err(path, where, f"Equation Model {eq.get('Model')!r} (Polynomial or FullRangeFraction)")  # type: ignore[union-attr]


def _fmt(v: float) -> str:
    return f"{v:.10g}"


def n42_document(spectra: list[Spectrum], *, instrument: str = "radseek 32-channel board",
                 detector_kind: str = "CsI", creator: str = "radseek", remarks: list[str] | None = None) -> str:
    """An N42.42-2011 document with one RadMeasurement per spectrum (written with explicit energy boundaries
    when a spectrum has them, polynomial coefficients otherwise)."""
    ns = N42_NS
    ET.register_namespace("", ns)
    root = ET.Element(f"{{{ns}}}RadInstrumentData", {"n42DocUUID": _uuid(spectra)})
    ET.SubElement(root, f"{{{ns}}}RadInstrumentDataCreatorName").text = creator
    rii = ET.SubElement(root, f"{{{ns}}}RadInstrumentInformation", {"id": "rii-1"})
    ET.SubElement(rii, f"{{{ns}}}RadInstrumentManufacturerName").text = "radseek"
    ET.SubElement(rii, f"{{{ns}}}RadInstrumentModelName").text = instrument
    ET.SubElement(rii, f"{{{ns}}}RadInstrumentClassCode").text = "Spectroscopic Personal Radiation Detector"
    rdi = ET.SubElement(root, f"{{{ns}}}RadDetectorInformation", {"id": "det-1"})
    ET.SubElement(rdi, f"{{{ns}}}RadDetectorCategoryCode").text = "Gamma"
    ET.SubElement(rdi, f"{{{ns}}}RadDetectorKindCode").text = detector_kind
    for i, sp in enumerate(spectra):
        ec = ET.SubElement(root, f"{{{ns}}}EnergyCalibration", {"id": f"ec-{i}"})
        if sp.boundaries_keV is not None:
            ET.SubElement(ec, f"{{{ns}}}EnergyBoundaryValues").text = " ".join(_fmt(v) for v in sp.boundaries_keV)
        else:
            ET.SubElement(ec, f"{{{ns}}}CoefficientValues").text = " ".join(_fmt(v) for v in sp.calibration)
    for i, sp in enumerate(spectra):
        meas = ET.SubElement(root, f"{{{ns}}}RadMeasurement", {"id": f"rm-{i}"})
        remark = sp.title or (remarks[i] if remarks and i < len(remarks) else "")
        if remark:
            ET.SubElement(meas, f"{{{ns}}}Remark").text = remark
        ET.SubElement(meas, f"{{{ns}}}MeasurementClassCode").text = {"background": "Background"}.get(
            sp.kind, "Foreground")
        ET.SubElement(meas, f"{{{ns}}}StartDateTime").text = sp.start_time or "1970-01-01T00:00:00Z"
        ET.SubElement(meas, f"{{{ns}}}RealTimeDuration").text = format_duration(sp.real_time_s or sp.live_time_s)
        spel = ET.SubElement(meas, f"{{{ns}}}Spectrum", {"id": f"rm-{i}-sp", "radDetectorInformationReference": "det-1",
                                                         "energyCalibrationReference": f"ec-{i}"})
        ET.SubElement(spel, f"{{{ns}}}LiveTimeDuration").text = format_duration(sp.live_time_s)
        counts = sp.counts
        text = " ".join(str(int(c)) if float(c).is_integer() else _fmt(c) for c in counts)
        ET.SubElement(spel, f"{{{ns}}}ChannelData", {"compressionCode": "None"}).text = text
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _uuid(spectra: list[Spectrum]) -> str:
    import hashlib
    import uuid

    h = hashlib.sha1()
    for sp in spectra:
        h.update(np.asarray(sp.counts, dtype=float).tobytes())
        h.update(str(sp.start_time).encode())
    return str(uuid.UUID(bytes=h.digest()[:16]))


def write_n42(path: str | Path, spectra: list[Spectrum], **kwargs) -> Path:
    p = Path(path)
    p.write_text(n42_document(spectra, **kwargs))
    return p


# ------------------------------------------------------------------------------------------------ RadiaCode


def read_radiacode_xml(path: str | Path, data: bytes | None = None) -> list[Spectrum]:
    """The spectrum (and the embedded background, if any) of a RadiaCode app XML export."""
    data = Path(path).read_bytes() if data is None else data
    root = _parse_xml(path, data)
    if _local(root.tag) != "ResultDataFile":
        raise _err(path, f"<{_local(root.tag)}>", "root element must be ResultDataFile (RadiaCode XML)")
    out = []
    for rd_i, rd in enumerate(root.iter("ResultData")):
        start = rd.find("StartTime")
        for tag, kind in (("EnergySpectrum", "foreground"), ("BackgroundEnergySpectrum", "background")):
            es = rd.find(tag)
            if es is None:
                continue
            where = f"ResultData[{rd_i}]/{tag}"
            sp_el = es.find("Spectrum")
            if sp_el is None:
                raise _err(path, where, "missing Spectrum")
            counts = _check_counts(path, where + "/Spectrum/DataPoint",
                                   [_float(path, where + f"/Spectrum/DataPoint[{i}]", d.text)
                                    for i, d in enumerate(sp_el.findall("DataPoint"))])
            n_el = es.find("NumberOfChannels")
            if n_el is not None and int(_float(path, where + "/NumberOfChannels", n_el.text)) != len(counts):
                raise _err(path, where + "/NumberOfChannels", f"says {n_el.text.strip()} but Spectrum has "  # type: ignore[union-attr]
                           f"{len(counts)} DataPoint")
            mt = es.find("MeasurementTime")
            if mt is None:
                raise _err(path, where, "missing MeasurementTime")
            live = _float(path, where + "/MeasurementTime", mt.text)
            if live <= 0:
                raise _err(path, where + "/MeasurementTime", f"must be > 0, got {live}")
            real = None
            lt = es.find("LiveTime")  # AtomSpectra / BecqMoni write it (0 when unknown); RadiaCode does not
            if lt is not None and _float(path, where + "/LiveTime", lt.text) != 0:
                real, live = live, _float(path, where + "/LiveTime", lt.text)
                if not 0 < live <= real * (1 + 1e-6):
                    raise _err(path, where + "/LiveTime", f"{live} must be > 0 and <= MeasurementTime {real}")
            coefs = es.findall("EnergyCalibration/Coefficients/Coefficient")
            cal = tuple(_float(path, where + f"/EnergyCalibration/Coefficients/Coefficient[{i}]", c.text)
                        for i, c in enumerate(coefs))
            order = es.find("EnergyCalibration/PolynomialOrder")
            if order is not None and coefs and int(_float(path, where + "/EnergyCalibration/PolynomialOrder",
                                                          order.text)) + 1 != len(cal):
                raise _err(path, where + "/EnergyCalibration", f"PolynomialOrder {order.text.strip()} needs "  # type: ignore[union-attr]
                           f"{int(float(order.text)) + 1} Coefficient, found {len(cal)}")  # type: ignore[arg-type]
            cal = _poly_cal(path, where + "/EnergyCalibration", cal, len(counts))
            name = es.find("SpectrumName")
            serial = es.find("SerialNumber")
            out.append(Spectrum(counts, live, real, cal, None,
                                (start.text or "").strip() if start is not None and kind == "foreground" else None,
                                (name.text or "").strip() if name is not None else "",
                                (serial.text or "").strip() if serial is not None else "", kind, str(path)))
    if not out:
        raise _err(path, "ResultDataFile", "no ResultData/EnergySpectrum")
    return out


# ------------------------------------------------------------------------------------------------ Ortec


def read_spe(path: str | Path, data: bytes | None = None) -> list[Spectrum]:
    """An Ortec ASCII .spe file."""
    data = Path(path).read_bytes() if data is None else data
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
             f"{sp.live_time_s:.10g} {sp.real_time_s or sp.live_time_s:.10g}", "$DATA:", f"0 {sp.n_channels - 1}"]
    lines += [str(int(c)) for c in sp.counts]
    lines += ["$MCA_CAL:", str(len(sp.calibration)), " ".join(f"{c:.9g}" for c in sp.calibration) + " keV"]
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)


_CHN_HEADER = struct.Struct("<hhh2sii8s4shh")


def read_chn(path: str | Path, data: bytes | None = None) -> list[Spectrum]:
    """An Ortec binary .chn file."""
    data = Path(path).read_bytes() if data is None else data
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
    head = _CHN_HEADER.pack(-1, 1, 1, b"00", round((sp.real_time_s or sp.live_time_s) / 0.02),
                            round(sp.live_time_s / 0.02), b"01JAN70*", b"0000", 0, sp.n_channels)
    body = np.asarray(sp.counts, dtype="<i4").tobytes()
    trailer = struct.pack("<hhfff", -102, 0, *cal[:3]) + bytes(512 - 16)
    Path(path).write_bytes(head + body + trailer)
    return Path(path)


# ------------------------------------------------------------------------------------------------ CSV


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


# ------------------------------------------------------------------------------------------------ dispatch


def _head(data: bytes) -> bytes:
    """The file's first 4 kB as ASCII-compatible bytes, without a byte-order mark or leading white space."""
    if data[:2] in (b"\xff\xfe", b"\xfe\xff"):  # UTF-16 XML
        return data[:8192].decode("utf-16", errors="replace").encode("utf-8", errors="replace").lstrip()
    return data[:4096].removeprefix(b"\xef\xbb\xbf").lstrip()


def detect_format(path: str | Path, data: bytes) -> str:
    head = _head(data)
    if data[:2] == b"\xff\xff":
        return "chn"
    if head.startswith(b"<"):
        if b"RadInstrumentData" in head or b"N42InstrumentData" in head:
            return "n42"
        if b"ResultDataFile" in head:
            return "xml"
    if head.startswith(b"$"):
        return "spe"
    fmt = SUFFIXES.get(Path(path).suffix.lower())
    if fmt is None:
        raise SpectrumFileError(f"{path}: unknown spectrum format (N42, RadiaCode XML, .spe, .chn or CSV)")
    return fmt


READERS = {"n42": read_n42, "xml": read_radiacode_xml, "spe": read_spe, "chn": read_chn, "csv": read_csv}


def read_spectra(path: str | Path, data: bytes | None = None) -> list[Spectrum]:
    """Every spectrum in a file, the format from its content (then its suffix)."""
    p = Path(path)
    if data is None:
        try:
            data = p.read_bytes()
        except FileNotFoundError:
            raise SpectrumFileError(f"{p}: file not found") from None
    fmt = detect_format(p, data)
    if fmt == "xml" and (b"RadInstrumentData" in _head(data) or b"N42InstrumentData" in _head(data)):
        fmt = "n42"
    return READERS[fmt](p, data)


def read_spectrum(path: str | Path, kind: str = "foreground") -> Spectrum:
    """The first spectrum of ``kind`` in a file (the first of any kind when none is marked)."""
    spectra = read_spectra(path)
    for sp in spectra:
        if sp.kind == kind:
            return sp
    return spectra[0]
