"""NPES JSON spectra (Nuclear Physics Energy Spectra; Open Gamma Project, github.com/OpenGammaProject/NPES-JSON).

The JSON format Gamma MCA (the web MCA that records RadiaCode devices) and Gammaspectacular's IMPULSE write; its
schema is published (``schema/npes-2.schema.json``):

- NPESv2: ``{"schemaVersion": "NPESv2", "data": [package, ...]}``; NPESv1: one package as the document;
- a package: ``resultData`` with ``energySpectrum`` (kind ``foreground``) and/or ``backgroundEnergySpectrum``
  (kind ``background``), ``startTime`` (ISO; the foreground's), ``deviceData`` (``deviceName``, ``softwareName``),
  ``sampleInfo`` (``name`` kept as the title);
- a spectrum: ``spectrum`` (counts), ``numberOfChannels`` (its length), ``measurementTime`` (s, the live time:
  the format records no other), ``validPulseCount``, ``energyCalibration`` (``polynomialOrder`` and
  ``coefficients`` lowest order first, keV, read as channel i's lower edge like the other formats; without one
  the channels stay channel numbers).

The schema's default ``measurementTime`` of 1 s is not assumed: a spectrum without one is refused.
"""

from __future__ import annotations

from pathlib import Path

from .core import Spectrum, _err, _poly_cal, make_spectrum
from .ndjson import _counts, read_json_object

KINDS = (("energySpectrum", "foreground"), ("backgroundEnergySpectrum", "background"))


def _spectrum(path, where: str, d, kind: str, start: str | None, meta: dict) -> Spectrum:
    if not isinstance(d, dict):
        raise _err(path, where, "must be an object (an energy spectrum)")
    counts = _counts(path, where, d.get("spectrum"))
    n = d.get("numberOfChannels")
    if n != len(counts):
        raise _err(path, f"{where}.numberOfChannels", f"says {n!r} but spectrum has {len(counts)} bins")
    live = d.get("measurementTime")
    if isinstance(live, bool) or not isinstance(live, (int, float)):
        raise _err(path, f"{where}.measurementTime", f"must be the measurement time in seconds, got {live!r}")
    cal: tuple[float, ...] = (0.0, 1.0)
    if (c := d.get("energyCalibration")) is not None:
        coefs = c.get("coefficients") if isinstance(c, dict) else None
        if not isinstance(coefs, list) or not coefs or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in coefs):
            raise _err(path, f"{where}.energyCalibration.coefficients", f"must be numbers, got {coefs!r}")
        if c.get("polynomialOrder") != len(coefs) - 1:
            raise _err(path, f"{where}.energyCalibration.polynomialOrder",
                       f"{c.get('polynomialOrder')!r} for {len(coefs)} coefficients")
        cal = _poly_cal(path, f"{where}.energyCalibration", coefs, len(counts))
    return make_spectrum(path, where, counts, float(live), None, calibration=cal, start_time=start, kind=kind,
                         meta={**meta, "valid_pulse_count": d.get("validPulseCount")}, title=meta["sample"])


def read_npes(path: str | Path, data: bytes | None = None) -> list[Spectrum]:
    """Every spectrum of an NPES document (module docstring), foreground before background in each package."""
    doc = read_json_object(path, data)
    version = doc.get("schemaVersion", "NPESv1")
    if version == "NPESv2":
        packages = doc.get("data")
        if not isinstance(packages, list) or not packages:
            raise _err(path, "data", "must be a non-empty list of data packages (NPESv2)")
        named = [(f"data[{i}]", p) for i, p in enumerate(packages)]
    elif version == "NPESv1":
        named = [("", doc)]
    else:
        raise _err(path, "schemaVersion", f"{version!r} (NPESv1 or NPESv2 read)")
    out = []
    for where, pkg in named:
        res = pkg.get("resultData") if isinstance(pkg, dict) else None
        pre = f"{where}.resultData" if where else "resultData"
        if not isinstance(res, dict):
            raise _err(path, pre, "missing (each data package holds its spectra there)")
        dev = pkg.get("deviceData") if isinstance(pkg.get("deviceData"), dict) else {}
        sample = pkg.get("sampleInfo") if isinstance(pkg.get("sampleInfo"), dict) else {}
        meta = {"device": str(dev.get("deviceName", "") or ""), "software": str(dev.get("softwareName", "") or ""),
                "sample": str(sample.get("name", "") or "")}
        start = res.get("startTime") if isinstance(res.get("startTime"), str) else None
        found = [(k, kind) for k, kind in KINDS if k in res]
        if not found:
            raise _err(path, pre, "holds neither energySpectrum nor backgroundEnergySpectrum")
        # the package's start time is the recording's: the background's own is not in the format
        out += [_spectrum(path, f"{pre}.{k}", res[k], kind, start if kind == "foreground" else None, meta)
                for k, kind in found]
    return out
