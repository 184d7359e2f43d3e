"""ANSI N42.42-2011 and N42.42-2006 readers and the N42.42-2011 writer."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from .core import (
    Spectrum,
    SpectrumFileError,
    _check_counts,
    _child,
    _children,
    _err,
    _floats,
    _local,
    _parse_xml,
    _poly_cal,
    _rising,
    format_duration,
    parse_duration,
    polynomial_edges,
    read_limited,
)

N42_NS = "http://physics.nist.gov/N42/2011/N42"


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
    data = read_limited(path) if data is None else data
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
        if sp.bin_edges_kev is not None:
            ET.SubElement(ec, f"{{{ns}}}EnergyBoundaryValues").text = " ".join(_fmt(v) for v in sp.bin_edges_kev)
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
        ET.SubElement(meas, f"{{{ns}}}RealTimeDuration").text = format_duration(sp.realtime or sp.livetime)
        spel = ET.SubElement(meas, f"{{{ns}}}Spectrum", {"id": f"rm-{i}-sp", "radDetectorInformationReference": "det-1",
                                                         "energyCalibrationReference": f"ec-{i}"})
        ET.SubElement(spel, f"{{{ns}}}LiveTimeDuration").text = format_duration(sp.livetime)
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
