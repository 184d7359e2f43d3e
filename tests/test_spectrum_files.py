"""Spectrum file readers and the N42 writer (radseek_io.spectrum_io), on the real RadiaCode-102 files."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from radseek_io import spectrum_io as sf

DATA = Path(__file__).resolve().parent / "data" / "real-spectra"


def test_radiacode_xml_reads_counts_time_calibration_serial():
    sp = sf.read_spectrum(DATA / "Cs137_b.xml")
    assert sp.n_channels == 1024
    assert sp.livetime == 300.0
    assert sp.counts.sum() == 83512
    assert sp.calibration == pytest.approx((-6.38159, 2.36593, 4.39819e-4))
    assert sp.serial == "RC-102-001272"
    # lower edge of channel i is c0 + c1 i + c2 i^2 (the N42 / SpecUtils convention)
    assert sp.edges_keV()[280] == pytest.approx(-6.38159 + 2.36593 * 280 + 4.39819e-4 * 280**2)


def test_n42_2011_from_radiacode_tools():
    sp = sf.read_spectrum(DATA / "data_am241.n42")
    assert sp.n_channels == 1024
    assert sp.livetime == 613.0 and sp.realtime == 613.0
    assert sp.calibration == pytest.approx((-6.2832313, 2.4383054, 0.0003818))
    assert sp.serial == "RC-102-000115"
    assert sp.kind == "foreground"
    assert sp.counts.sum() == 306058


def test_background_and_ba133_read():
    assert sf.read_spectrum(DATA / "bg.xml").livetime == 1800.0
    assert sf.read_spectrum(DATA / "Ba133_a.xml").counts.sum() == 207680


@pytest.mark.parametrize("name,total", [("Co60_a.xml", 61243), ("Eu152_b.xml", 144169)])
def test_the_same_devices_other_nuclides_read(name, total):
    sp = sf.read_spectrum(DATA / name)
    assert sp.livetime == 300.0 and sp.counts.sum() == total and sp.serial == "RC-102-001272"


@pytest.mark.parametrize("writer,suffix", [(sf.write_spe, ".spe"), (sf.write_chn, ".chn"), (sf.write_csv, ".csv")])
def test_ortec_and_csv_round_trip(tmp_path, writer, suffix):
    sp = sf.read_spectrum(DATA / "Cs137_b.xml")
    p = writer(tmp_path / f"cs{suffix}", sp)
    back = sf.read_spectrum(p)
    np.testing.assert_array_equal(back.counts, sp.counts)
    assert back.livetime == pytest.approx(300.0)
    np.testing.assert_allclose(back.edges_keV(), sp.edges_keV(), rtol=1e-6, atol=1e-3)  # .chn stores float32


def test_n42_writer_round_trip_with_boundaries_and_background(tmp_path):
    edges = np.linspace(40, 3000, 33)
    fg = sf.Spectrum(np.arange(32.0), 10.0, 12.0, bin_edges_kev=edges, start_time="2026-01-01T00:00:00Z", title="d0")
    bg = sf.Spectrum(np.ones(1024), 100.0, calibration=(1.0, 3.0), kind="background")
    p = sf.write_n42(tmp_path / "x.n42", [fg, bg])
    a, b = sf.read_n42(p)
    np.testing.assert_array_equal(a.counts, fg.counts)
    np.testing.assert_allclose(a.bin_edges_kev, edges)
    assert (a.livetime, a.realtime, a.title) == (10.0, 12.0, "d0")
    assert b.kind == "background" and b.calibration == (1.0, 3.0)
    assert sf.read_spectrum(p, kind="background").livetime == 100.0


def test_n42_counted_zeroes(tmp_path):
    text = (DATA / "data_am241.n42").read_text()
    doc = text.replace('compressionCode="None">', 'compressionCode="CountedZeroes">', 1)
    sp = sf.read_spectrum(DATA / "data_am241.n42")
    packed = []
    zeros = 0
    for c in sp.counts:
        if c == 0:
            zeros += 1
            continue
        if zeros:
            packed += [0, zeros]
            zeros = 0
        packed.append(int(c))
    if zeros:
        packed += [0, zeros]
    start = doc.index('compressionCode="CountedZeroes">') + len('compressionCode="CountedZeroes">')
    end = doc.index("</ChannelData>")
    doc = doc[:start] + " ".join(map(str, packed)) + doc[end:]
    (tmp_path / "cz.n42").write_text(doc)
    np.testing.assert_array_equal(sf.read_spectrum(tmp_path / "cz.n42").counts, sp.counts)


@pytest.mark.parametrize("mutate,expect", [
    (lambda t: t.replace("<MeasurementTime>300</MeasurementTime>", "<MeasurementTime>abc</MeasurementTime>"),
     "EnergySpectrum/MeasurementTime: not a number"),
    (lambda t: t.replace("<DataPoint>21</DataPoint>", "<DataPoint>-1</DataPoint>", 1), "DataPoint"),
    (lambda t: t.replace("<NumberOfChannels>1024", "<NumberOfChannels>1000"), "NumberOfChannels"),
    (lambda t: t[: len(t) // 2], "not well-formed XML"),
])
def test_radiacode_errors_name_file_and_element(tmp_path, mutate, expect):
    p = tmp_path / "bad.xml"
    p.write_text(mutate((DATA / "Cs137_b.xml").read_text()))
    with pytest.raises(sf.SpectrumFileError) as exc:
        sf.read_spectrum(p)
    assert str(p) in str(exc.value) and expect in str(exc.value)


#: a billion-laughs DOCTYPE: ten levels of ten references each, 10^10 "lol"s once expanded
LAUGHS = (b'<!DOCTYPE r [<!ENTITY l0 "lol">'
          + b"".join(b'<!ENTITY l%d "%s">' % (k, b"&l%d;" % (k - 1) * 10) for k in range(1, 11)) + b"]>",
          b"&l10;", "limit on input amplification")


@pytest.mark.parametrize("name, element", [("Cs137_b.xml", b"<SerialNumber>"),
                                           ("data_am241.n42", b"<RadInstrumentModelName>")])
def test_entity_expansion_and_external_entities_are_refused(tmp_path, name, element):
    """Issue 34's held XML probes, kept: a billion-laughs file and one whose entity names a local file (XXE) are
    refused as not well-formed, naming the file; nothing of the named file reaches the message or a field."""
    secret = tmp_path / "secret.txt"
    secret.write_text("radseek-xxe-secret")
    xxe = (b'<!DOCTYPE r [<!ENTITY x SYSTEM "file://%s">]>' % str(secret).encode(), b"&x;", "undefined entity &x;")
    data = (DATA / name).read_bytes()
    after_decl = data.index(b"?>") + 2
    hostile = tmp_path / f"hostile-{name}"
    for doctype, ref, why in (LAUGHS, xxe):
        hostile.write_bytes(data[:after_decl] + doctype + data[after_decl:].replace(element, element + ref, 1))
        with pytest.raises(sf.SpectrumFileError, match=f"not well-formed XML \\({why}") as exc:
            sf.read_spectrum(hostile)
        assert str(hostile) in str(exc.value) and "radseek-xxe-secret" not in str(exc.value)
    hostile.write_bytes(data[:after_decl] + xxe[0] + data[after_decl:])  # the control: declared, never used
    assert sf.read_spectrum(hostile).counts.sum() > 0


def test_n42_errors_name_element(tmp_path):
    text = (DATA / "data_am241.n42").read_text()
    p = tmp_path / "bad.n42"
    p.write_text(text.replace("<LiveTimeDuration>PT613S", "<LiveTimeDuration>613 s"))
    with pytest.raises(sf.SpectrumFileError, match=r"bad\.n42: RadMeasurement\[0\] id='rm-fg'/Spectrum\[0\]/"
                                                    r"LiveTimeDuration: not an xs:duration"):
        sf.read_spectrum(p)
    p.write_text(text.replace('energyCalibrationReference="ec-fg"', 'energyCalibrationReference="nope"'))
    with pytest.raises(sf.SpectrumFileError, match="energyCalibrationReference 'nope'"):
        sf.read_spectrum(p)


def test_spe_and_chn_errors(tmp_path):
    p = tmp_path / "bad.spe"
    p.write_text("$MEAS_TIM:\n10 10\n$DATA:\n0 3\n1\n2\n")
    with pytest.raises(sf.SpectrumFileError, match=r"bad\.spe: \$DATA:: range 0..3 needs 4 counts, found 2"):
        sf.read_spectrum(p)
    c = tmp_path / "bad.chn"
    c.write_bytes(struct.pack("<hhh2sii8s4shh", -1, 1, 1, b"00", 50, 50, b"01JAN70*", b"0000", 0, 100) + b"\0" * 40)
    with pytest.raises(sf.SpectrumFileError, match=r"bad\.chn: channel data \(bytes 32..432\): file ends at byte 72"):
        sf.read_spectrum(c)


def test_spe_export_opens_in_specutils(tmp_path):
    """The .spe writer read by an independent reader (InterSpec's SpecUtils, as an IAEA SPE): counts, live and real
    time, start time and the calibration's channel energies. (becquerel was this reader: its import compiles its
    numba kernels, 9 s of CPU a test run, for a 10 ms read.)"""
    import SpecUtils  # InterSpec's library (sandiaspecutils, dev dependency)
    sp = sf.read_spectrum(DATA / "Cs137_b.xml")
    p = sf.write_spe(tmp_path / "cs.spe", sp)
    f = SpecUtils.SpecFile()
    f.loadFile(str(p), SpecUtils.ParserType.SpeIaea)  # raises if it is not an IAEA SPE it can read
    assert f.numMeasurements() == 1
    m = f.measurements()[0]
    np.testing.assert_array_equal(np.asarray(m.gammaCounts()), sp.counts)
    assert m.liveTime() == pytest.approx(sp.livetime) and m.realTime() == pytest.approx(sp.realtime or sp.livetime)
    assert m.startTime().isoformat() == sp.start_time
    edges = sp.edges_keV()
    for k in (0, 1, sp.n_channels // 2, sp.n_channels - 1):
        assert m.gammaChannelLower(k) == pytest.approx(edges[k], abs=1e-3)


def test_n42_export_opens_in_specutils(tmp_path):
    import SpecUtils  # InterSpec's library (sandiaspecutils, dev dependency)
    sp = sf.read_spectrum(DATA / "Cs137_b.xml")
    p = sf.write_n42(tmp_path / "cs.n42", [sp])
    f = SpecUtils.SpecFile()
    f.loadFile(str(p), SpecUtils.ParserType.Auto)
    m = f.measurements()[0]
    assert m.gammaCountSum() == pytest.approx(sp.counts.sum())
    assert m.gammaChannelLower(1) == pytest.approx(sp.edges_keV()[1], abs=1e-3)


REAL = [(DATA / n).read_bytes() for n in ("Cs137_b.xml", "data_am241.n42")]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(which=st.integers(0, 1), pos=st.floats(0, 1), cut=st.integers(0, 200), junk=st.binary(max_size=40))
def test_fuzzed_xml_raises_only_spectrum_file_error(which, pos, cut, junk):
    data = REAL[which]
    i = int(pos * len(data))
    mutated = data[:i] + junk + data[i + cut:]
    try:
        sp = sf.read_spectra(Path("fuzz.n42" if which else "fuzz.xml"), mutated)
    except sf.SpectrumFileError as exc:
        assert "fuzz." in str(exc)
    else:
        assert all(np.all(s.counts >= 0) and s.livetime > 0 for s in sp)


@settings(max_examples=80, deadline=None)
@given(data=st.binary(max_size=600), suffix=st.sampled_from([".spe", ".chn", ".csv", ".n42", ".xml"]))
def test_fuzzed_bytes_raise_only_spectrum_file_error(data, suffix):
    try:
        sp = sf.read_spectra(Path("fuzz" + suffix), data)
    except sf.SpectrumFileError as exc:
        assert "fuzz" in str(exc)
    else:
        assert all(np.all(s.counts >= 0) for s in sp)


@settings(max_examples=40, deadline=None)
@given(counts=st.lists(st.integers(0, 10**6), min_size=2, max_size=300), live=st.floats(0.01, 1e5),
       c0=st.floats(-20, 20), c1=st.floats(0.1, 10))
def test_writers_round_trip_any_spectrum(tmp_path_factory, counts, live, c0, c1):
    d = tmp_path_factory.mktemp("rt")
    sp = sf.Spectrum(np.array(counts, dtype=float), live, calibration=(c0, c1))
    for writer, suffix in ((sf.write_spe, ".spe"), (sf.write_csv, ".csv"), (sf.write_n42, ".n42")):
        p = d / f"s{suffix}"
        writer(p, [sp]) if writer is sf.write_n42 else writer(p, sp)
        back = sf.read_spectrum(p)
        np.testing.assert_array_equal(back.counts, sp.counts)
        assert back.livetime == pytest.approx(live, rel=1e-6)


# ------------------------------------------------------------------------ files from other devices and tools

BQ = Path(__file__).resolve().parent / "data" / "becquerel"


def test_digibase_spe_all_zero_calibration_means_uncalibrated():
    # a real Maestro file whose $MCA_CAL is 0 0 0: read as channel numbers, not as every channel at 0 keV
    sp = sf.read_spectrum(BQ / "digibase_5min_30_1.spe")
    assert (sp.n_channels, sp.counts.sum(), sp.livetime, sp.realtime) == (1024, 892301, 296.0, 300.0)
    assert sp.calibration == (0.0, 1.0)
    assert np.all(np.diff(sp.edges_keV()) > 0)


def test_spe_bom_and_non_rising_calibration(tmp_path):
    body = "$SPEC_ID:\r\nx\r\n$MEAS_TIM:\r\n10 11\r\n$DATA:\r\n0 3\r\n1\r\n2\r\n3\r\n4\r\n$MCA_CAL:\r\n2\r\n"
    p = tmp_path / "a.spe"
    p.write_bytes(b"\xef\xbb\xbf" + (body + "1 2 keV\r\n").encode())
    sp = sf.read_spectrum(p)
    assert sp.title == "x" and sp.calibration == (1.0, 2.0) and sp.counts.sum() == 10
    p.write_bytes((body + "5 -2 keV\r\n").encode())
    with pytest.raises(sf.SpectrumFileError, match=r"a\.spe: \$MCA_CAL:: energy calibration .* does not rise"):
        sf.read_spectrum(p)


N42_2011_HEAD = ('<?xml version="1.0"?>\n<RadInstrumentData xmlns="http://physics.nist.gov/N42/2011/N42">\n'
                 '<EnergyCalibration id="ec"><CoefficientValues>0 3 0</CoefficientValues>{dev}</EnergyCalibration>\n')


def test_n42_compression_attribute_as_avid_writes_it(tmp_path):
    # Radiation Solutions' AVID writes <ChannelData Compression="CountedZeroes"> in N42-2011 files (SpecUtils
    # accepts both spellings); read as uncompressed, "0 4" became two channels instead of four zeros
    doc = (N42_2011_HEAD.format(dev="") + '<RadMeasurement id="m"><MeasurementClassCode>Foreground'
           '</MeasurementClassCode><RealTimeDuration>PT1S</RealTimeDuration>'
           '<Spectrum id="s" energyCalibrationReference="ec" radDetectorInformationReference="d1">'
           '<LiveTimeDuration>PT0.999S</LiveTimeDuration><ChannelData Compression="CountedZeroes">'
           '0 4 22 16 0 2 5</ChannelData></Spectrum></RadMeasurement></RadInstrumentData>\n')
    (tmp_path / "avid.n42").write_text(doc)
    sp = sf.read_spectrum(tmp_path / "avid.n42")
    np.testing.assert_array_equal(sp.counts, [0, 0, 0, 0, 22, 16, 0, 0, 5])
    assert sp.meta["detector"] == "d1" and sp.livetime == 0.999
    (tmp_path / "bad.n42").write_text(doc.replace('Compression="CountedZeroes"', 'Compression="Zip"'))
    with pytest.raises(sf.SpectrumFileError, match=r"bad\.n42: .*Spectrum\[0\]/ChannelData: unknown compressionCode"):
        sf.read_spectrum(tmp_path / "bad.n42")


def test_n42_with_interspec_undeclared_prefix_and_deviation_pairs(tmp_path):
    # InterSpec saves <DHS:InterSpec> without declaring DHS (expat: "unbound prefix"), and GADRAS deviation
    # pairs as EnergyValues / EnergyDeviationValues; a constant deviation d shifts every channel edge by d
    dev = "<EnergyValues>0 500 3000</EnergyValues><EnergyDeviationValues>-1 -1 -1</EnergyDeviationValues>"
    doc = (N42_2011_HEAD.format(dev=dev) + '<RadMeasurement id="m"><Spectrum id="s" energyCalibrationReference="ec">'
           '<LiveTimeDuration>PT10S</LiveTimeDuration><ChannelData compressionCode="None">1 2 3 4</ChannelData>'
           '</Spectrum></RadMeasurement>\n<DHS:InterSpec version="1"><DHS:Peaks/></DHS:InterSpec>\n'
           '</RadInstrumentData>\n')
    (tmp_path / "is.n42").write_text(doc)
    sp = sf.read_spectrum(tmp_path / "is.n42")
    assert sp.counts.sum() == 10 and sp.kind == "foreground"
    np.testing.assert_allclose(sp.edges_keV(), np.arange(5) * 3.0 - 1.0)
    # a smooth deviation curve: SpecUtils' spline through (E - d, d), flat beyond the last pair
    doc2 = doc.replace("-1 -1 -1", "0 4 0").replace("0 500 3000", "0 6 12")
    (tmp_path / "is2.n42").write_text(doc2)
    e = sf.read_spectrum(tmp_path / "is2.n42").edges_keV()
    assert e[0] == 0.0 and e[4] == 12.0 and e[1] > 3.0 and e[2] > 6.0


N42_2006 = """<?xml version="1.0"?>
<N42InstrumentData xmlns="http://physics.nist.gov/Divisions/Div846/Gp4/ANSIN4242/2005/ANSIN4242">
<Measurement><InstrumentInformation><InstrumentID>x</InstrumentID></InstrumentInformation>
<DetectorData><StartTime>2016-02-04T20:28:33.000Z</StartTime><SampleRealTime>PT2S</SampleRealTime>
<DetectorMeasurement Detector="VD1" DetectorType="Gamma"><SpectrumMeasurement>
<Spectrum CalibrationIDs="Lin"><RealTime>PT0.999998S</RealTime><LiveTime>PT0.999718S</LiveTime>
<SourceType>Item</SourceType><ChannelData Compression="CountedZeroes">0 2 7 0 1 3</ChannelData></Spectrum>
</SpectrumMeasurement></DetectorMeasurement>
<DetectorMeasurement Detector="VD1" DetectorType="Neutron"><SpectrumMeasurement><Spectrum>
<LiveTime>PT1S</LiveTime><ChannelData>5</ChannelData></Spectrum></SpectrumMeasurement></DetectorMeasurement>
</DetectorData></Measurement>
<Measurement><Spectrum Type="PHA"><LiveTime>299.5</LiveTime><RealTime>300</RealTime><SourceType>Background</SourceType>
<Calibration Type="Energy" EnergyUnits="MeV"><Equation Model="FullRangeFraction"><Coefficients>0 3</Coefficients>
</Equation></Calibration><ChannelData>1, 2, 3</ChannelData></Spectrum></Measurement>
<Calibration Type="Energy" EnergyUnits="keV" ID="Lin"><Equation Model="Polynomial"><Coefficients>1 3</Coefficients>
</Equation></Calibration>
</N42InstrumentData>
"""


def test_n42_2006(tmp_path):
    # N42.42-2006 (ORTEC portals, RSI AVID / RadAssist, older InterSpec examples) was refused outright
    p = tmp_path / "old.N42"
    p.write_text(N42_2006)
    fg, bg = sf.read_spectra(p)
    np.testing.assert_array_equal(fg.counts, [0, 0, 7, 0, 3])
    assert (fg.livetime, fg.realtime, fg.calibration, fg.kind) == (0.999718, 0.999998, (1.0, 3.0), "foreground")
    assert fg.start_time == "2016-02-04T20:28:33.000Z" and fg.meta["detector"] == "VD1"
    assert (bg.kind, bg.livetime, bg.realtime) == ("background", 299.5, 300.0)
    np.testing.assert_allclose(bg.edges_keV(), [0, 1000, 2000, 3000])  # FullRangeFraction in MeV
    assert sf.detect_format(tmp_path / "old.xml", N42_2006.encode()) == "n42"
    p.write_text(N42_2006.replace('ID="Lin"', 'ID="Other"'))
    with pytest.raises(sf.SpectrumFileError, match=r"old\.N42: Spectrum\[0\] Detector='VD1': CalibrationIDs 'Lin'"):
        sf.read_spectra(p)


def test_resultdatafile_live_time_and_polynomial_order(tmp_path):
    # AtomSpectra / BecqMoni write <LiveTime> beside <MeasurementTime> (the real time) in the same format
    text = (DATA / "Cs137_b.xml").read_text()
    p = tmp_path / "as.xml"
    p.write_text(text.replace("<MeasurementTime>300</MeasurementTime>",
                              "<MeasurementTime>300</MeasurementTime><LiveTime>297.5</LiveTime>"))
    sp = sf.read_spectrum(p)
    assert (sp.livetime, sp.realtime) == (297.5, 300.0)
    # radiacode-tools' data_invalid_cal_inconsistent_order.xml: order 2 but the quadratic term deleted
    p.write_text(text.replace("<Coefficient>4.39819E-4</Coefficient>", ""))
    with pytest.raises(sf.SpectrumFileError, match=r"EnergySpectrum/EnergyCalibration: PolynomialOrder 2 needs 3"):
        sf.read_spectrum(p)
