"""Gamma spectrum files, one module per format: read N42 (ANSI N42.42-2011 and 2006), RadiaCode XML, JSON and
spectrograms (.rcspg), radiacode-tools logs (.ndjson), Ortec .spe / .chn and CSV; write N42.

Every reader returns :class:`Spectrum` objects (counts per channel, live and real time, energy calibration); every
error is a :class:`SpectrumFileError` naming the file and the element, section or byte offset that is wrong.

Which library: ``becquerel`` 0.7 (PyPI) was checked on Python 3.11 here. It reads Ortec .spe, Canberra .cnf, .spc
and IEC 1455, but not N42, RadiaCode XML, .chn or CSV; it pulls numba, pandas, lmfit and black, prints a line per
file read and rejects an .spe without ``$DATE_MEA``. So the readers here are small and validated, and
``tests/test_spectrum_files.py`` checks the .spe and N42 writers against SpecUtils (``sandiaspecutils``, the library
InterSpec is built on).

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
- **CSV** (:func:`.csvfile.read_csv`): channel / energy / counts columns in any order, the channel column
  honoured, live time from a header line or ``--live-time``.
- **RadiaCode spectrogram** (:mod:`.rcspg`), **radiacode-tools log** (:mod:`.ndjson`, streamed, frames from
  cumulative spectra, GNSS fixes), **RadiaCode JSON** (:mod:`.radiacode_json`), **NPES JSON** (Gamma MCA,
  IMPULSE; :mod:`.npes`).

Bad input: counts non-finite, negative or above :data:`MAX_COUNTS_PER_CHANNEL`, live or real times <= 0 or above
:data:`MAX_TIME_S`, a live time above the real time, more than :data:`MAX_CHANNELS` channels, and files above
:data:`MAX_FILE_BYTES` are refused with a :class:`SpectrumFileError` naming the file and the field.
"""

from __future__ import annotations

from pathlib import Path

from .chn import read_chn, write_chn
from .core import (
    MAX_CHANNELS,
    MAX_COUNTS_PER_CHANNEL,
    MAX_FILE_BYTES,
    MAX_TIME_S,
    Spectrum,
    SpectrumFileError,
    format_duration,
    open_stream,
    parse_duration,
    polynomial_edges,
    read_limited,
)
from .csvfile import read_commented_csv, read_csv, write_csv
from .n42 import N42_NS, n42_document, read_n42, write_n42
from .ndjson import read_ndjson
from .npes import read_npes
from .radiacode_json import read_radiacode_json
from .radiacode_xml import read_radiacode_xml
from .rcspg import read_rcspg
from .spe import read_spe, write_spe

__all__ = [
    "MAX_CHANNELS", "MAX_COUNTS_PER_CHANNEL", "MAX_FILE_BYTES", "MAX_TIME_S", "N42_NS", "READERS", "STREAMED",
    "SUFFIXES", "Spectrum", "SpectrumFileError", "detect_format", "format_duration", "format_of", "n42_document",
    "parse_duration", "polynomial_edges", "read_chn", "read_commented_csv", "read_csv", "read_n42", "read_ndjson",
    "read_npes", "read_radiacode_json", "read_radiacode_xml", "read_rcspg", "read_spe", "read_spectra",
    "read_spectrum", "write_chn", "write_csv", "write_n42", "write_spe",
]

SUFFIXES = {".n42": "n42", ".xml": "xml", ".spe": "spe", ".chn": "chn", ".csv": "csv", ".txt": "csv",
            ".tsv": "csv", ".rcspg": "rcspg", ".json": "json", ".ndjson": "ndjson", ".jsonl": "ndjson"}

def _head(data: bytes) -> bytes:
    """The file's first 4 kB as ASCII-compatible bytes, without a byte-order mark or leading white space."""
    if data[:2] in (b"\xff\xfe", b"\xfe\xff"):  # UTF-16 XML
        return data[:8192].decode("utf-16", errors="replace").encode("utf-8", errors="replace").lstrip()
    return data[:4096].removeprefix(b"\xef\xbb\xbf").lstrip()


def detect_format(path: str | Path, data: bytes) -> str:
    """The format of a file from its first bytes ``data`` (then its suffix): a key of :data:`READERS`."""
    head = _head(data)
    suffix = Path(path).suffix.lower()
    if data[:2] == b"\xff\xff":
        return "chn"
    if head.startswith(b"<"):
        if b"RadInstrumentData" in head or b"N42InstrumentData" in head:
            return "n42"
        if b"ResultDataFile" in head:
            return "xml"
    if head.startswith(b"$"):
        return "spe"
    if head.startswith(b"Spectrogram:"):
        return "rcspg"
    if head.startswith(b"{"):
        if b'"NPESv' in head or b'"resultData"' in head:
            return "npes"
        if suffix in (".ndjson", ".jsonl"):
            return "ndjson"
        if suffix == ".json":
            return "json"
        first, _, rest = head.partition(b"\n")
        return "ndjson" if rest.lstrip().startswith(b"{") else "json"
    fmt = SUFFIXES.get(suffix)
    if fmt is None:
        raise SpectrumFileError(f"{path}: unknown spectrum format (N42, RadiaCode XML / JSON / .rcspg, "
                                "radiacode-tools .ndjson, .spe, .chn or CSV)")
    return fmt


READERS = {"n42": read_n42, "xml": read_radiacode_xml, "spe": read_spe, "chn": read_chn, "csv": read_csv,
           "rcspg": read_rcspg, "json": read_radiacode_json, "ndjson": read_ndjson, "npes": read_npes}
#: formats read line by line from the file (never held whole in memory)
STREAMED = {"rcspg", "ndjson"}


def read_spectra(path: str | Path, data: bytes | None = None, *, live_time_s: float | None = None,
                 max_bytes: int | None = None) -> list[Spectrum]:
    """Every spectrum in a file, the format from its content (then its suffix). ``live_time_s`` is the live time
    of a CSV that has none; ``max_bytes`` raises the size limit (:data:`MAX_FILE_BYTES`)."""
    p = Path(path)
    fmt = format_of(p, data, max_bytes)
    if data is None and fmt not in STREAMED:
        data = read_limited(p, max_bytes)
    if fmt == "csv":
        return read_csv(p, data, live_time_s=live_time_s)
    if fmt in STREAMED:
        return READERS[fmt](p, data, max_bytes=max_bytes)
    return READERS[fmt](p, data)


def format_of(path: str | Path, data: bytes | None = None, max_bytes: int | None = None) -> str:
    """The format of a file (its first 8 kB read, the size limit checked, when ``data`` is not given)."""
    p = Path(path)
    if data is None:
        with open_stream(p, None, max_bytes) as f:
            data = f.read(8192)
    fmt = detect_format(p, data)
    if fmt == "xml" and (b"RadInstrumentData" in _head(data) or b"N42InstrumentData" in _head(data)):
        fmt = "n42"
    return fmt


def read_spectrum(path: str | Path, kind: str = "foreground", **kwargs) -> Spectrum:
    """The first spectrum of ``kind`` in a file (the first of any kind when none is marked)."""
    spectra = read_spectra(path, **kwargs)
    for sp in spectra:
        if sp.kind == kind:
            return sp
    return spectra[0]
