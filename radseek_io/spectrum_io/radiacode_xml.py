"""RadiaCode app XML export (``ResultDataFile``)."""

from __future__ import annotations

from pathlib import Path

from .core import Spectrum, SpectrumFileError, _check_counts, _err, _float, _local, _parse_xml, _poly_cal, read_limited


def read_radiacode_xml(path: str | Path, data: bytes | None = None) -> list[Spectrum]:
    """The spectrum (and the embedded background, if any) of a RadiaCode app XML export."""
    data = read_limited(path) if data is None else data
    root = _parse_xml(path, data)
    if _local(root.tag) != "ResultDataFile":
        raise _err(path, f"<{_local(root.tag)}>", "root element must be ResultDataFile (RadiaCode XML)")
    out = []
    for rd_i, rd in enumerate(root.iter("ResultData")):
        # one StartTime per layer, in layer order (radiacode-tools RcSpectrum writes and reads them so)
        starts = [(e.text or "").strip() or None for e in rd.findall("StartTime")]
        layers = (("EnergySpectrum", "foreground"), ("BackgroundEnergySpectrum", "background"))
        for layer, (tag, kind) in enumerate(layers):
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
            try:
                out.append(Spectrum(counts, live, real, cal, None, starts[layer] if layer < len(starts) else None,
                                    (name.text or "").strip() if name is not None else "",
                                    (serial.text or "").strip() if serial is not None else "", kind, str(path)))
            except SpectrumFileError as exc:
                raise _err(path, where, str(exc).split(": ", 1)[-1]) from None
    if not out:
        raise _err(path, "ResultDataFile", "no ResultData/EnergySpectrum")
    return out
