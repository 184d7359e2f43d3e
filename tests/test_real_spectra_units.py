"""Two more RadiaCode units (issue 32): RC-102-013789 (tests/data/real-spectra-rc102-013789, MIT, app XML) and
RC-103-006489 (tests/data/real-spectra-rc103-006489, CC BY 4.0, CSV with a formula calibration). Each file reads as
an independent parse of its text says; natural uranium without its daughters (uranium glass and glaze) as a
calibration source; the joint response of a unit predicting its other sources with no refit."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import numpy as np
import pytest

from radseek.photon_lines import FRESH_URANIUM, equilibrium_lines, natural_uranium_activity_ratio, source_lines
from radseek_io.spectrum_io import SpectrumFileError, read_spectrum

DATA = Path(__file__).resolve().parent / "data" / "real-spectra-rc102-013789"
RC103 = Path(__file__).resolve().parent / "data" / "real-spectra-rc103-006489"
#: the publisher's calibration/SHA256SUMS.txt (github.com/Fisicas/radiacode-flight-spectroscopy, 38ddbc7)
RC103_SHA256 = {
    "Am-241_energy_calibrated.csv": "9fe51909747a42fc04a9e02237efbca3e3f40f1f8d807a4774929c39781498fb",
    "Ra-226_energy_calibrated.csv": "b2089032c9ee5446103f60fbd0da3e6181ea1a395434b830e452f12dd7931f0e",
    "Th-232_energy_calibrated.csv": "bfc24181eb3d9f8cb4fa63aa15e9201c479b7197e08834040d40102f4d604da6",
    "U-238-U-235-FiestaWare_energy_calibrated.csv": "d48126feb3518f1cacd776676082d669c273687570eedb36ac4b4585e72305dc",
}
FILES = ("am-95-his07.xml", "np-93-his07.xml", "ra-88-spd.xml", "rn-86-spd.xml", "th-90-wt20.xml",
         "u-92-glass.xml")


def _regex_parse(path: Path) -> tuple[np.ndarray, float, tuple[float, ...], str]:
    """The same file read with regular expressions, not XML: counts, MeasurementTime, coefficients, serial."""
    text = path.read_text()
    counts = np.array([float(x) for x in re.findall(r"<DataPoint>(\d+)</DataPoint>", text)])
    live = float(re.search(r"<MeasurementTime>(\d+)</MeasurementTime>", text).group(1))
    cal = tuple(float(x) for x in re.findall(r"<Coefficient>([-+0-9.eE]+)</Coefficient>", text))
    serial = re.search(r"<SerialNumber><!\[CDATA\[([^\]]*)\]\]></SerialNumber>", text).group(1)
    return counts, live, cal, serial


@pytest.mark.parametrize("name", FILES)
def test_each_file_reads_as_its_text_says(name):
    sp = read_spectrum(DATA / name)
    counts, live, cal, serial = _regex_parse(DATA / name)
    assert sp.kind == "foreground" and sp.serial == serial == "RC-102-013789"
    assert len(sp.counts) == len(counts) == 1024
    np.testing.assert_array_equal(sp.counts, counts)
    assert sp.livetime == live
    # channel i's lower edge is c0 + c1 i + c2 i^2 keV
    e = sp.edges_keV()
    i = np.array([0, 512, 1023])
    np.testing.assert_allclose(e[i], cal[0] + cal[1] * i + cal[2] * i ** 2, rtol=1e-9)


def test_natural_uranium_is_u238_with_its_short_lived_progeny_and_u235_at_the_natural_ratio():
    # activity ratio U-235 / U-238 of natural uranium: 0.046 (e.g. IAEA TRS-476); from the atom ratio and half-lives
    assert natural_uranium_activity_ratio() == pytest.approx(0.0461, abs=5e-4)
    lines = dict(source_lines(FRESH_URANIUM))
    # Pa-234m's 1001 keV (under Th-234, at U-238's rate) and U-235's 185.7 keV at 0.572 x the ratio
    assert lines[1001.03] == pytest.approx(dict(source_lines("Pa-234m"))[1001.03], rel=1e-6)
    assert lines[185.715] == pytest.approx(0.572 * natural_uranium_activity_ratio(), rel=0.01)
    # no radium: none of Bi-214's or Pb-214's lines, which the equilibrium chain has
    chain = dict(equilibrium_lines("U-238"))
    for e in (609.312, 351.932, 1764.49):
        assert e in chain and e not in lines


@pytest.mark.parametrize("name", sorted(RC103_SHA256))
def test_rc103_csv_reads_with_its_formula_calibration(name):
    """``# Calibration,E_keV = 5.15 + 2.43*c + 0.000375*c^2`` (a formula, not numbers) and ``# MeasurementTime,532``:
    the file as published (its SHA-256), counts as the column says, the energy column where the formula puts it."""
    path = RC103 / name
    assert hashlib.sha256(path.read_bytes()).hexdigest() == RC103_SHA256[name]
    text = path.read_text()
    rows = np.array([[float(x) for x in ln.split(",")] for ln in text.splitlines()
                     if ln and ln[0].isdigit()])
    c = [float(x) for x in re.search(r"E_keV = ([-0-9.e]+) \+ ([-0-9.e]+)\*c \+ ([-0-9.e]+)\*c\^2", text).groups()]
    sp = read_spectrum(path)
    assert sp.serial == "RC-103-006489" and sp.kind == "foreground"
    assert sp.livetime == float(re.search(r"# MeasurementTime,(\d+)", text).group(1))
    np.testing.assert_array_equal(sp.counts, rows[:, 1])
    assert sp.calibration == pytest.approx(tuple(c), rel=1e-12)
    np.testing.assert_allclose(sp.edges_keV()[:-1], rows[:, 0], atol=5e-7)


@pytest.mark.parametrize("line,coefs", [
    ("# calibration: 1.5 2.5 0.001", (1.5, 2.5, 0.001)),
    ("# Calibration,E_keV = 5.1 + 2.4*c + 0.0003*c^2", (5.1, 2.4, 0.0003)),
    ("# calibration: E = -3e-1 + 0.003 * ch**2 + 2.5*ch", (-0.3, 2.5, 0.003)),
    ("# calibration: E = 2.5*x - 4", (-4.0, 2.5)),
])
def test_calibration_line_as_numbers_or_formula(tmp_path, line, coefs):
    f = tmp_path / "s.csv"
    f.write_text(f"{line}\n# live_time_s: 10\nchannel,counts\n" + "".join(f"{i},{i % 7}\n" for i in range(64)))
    assert read_spectrum(f).calibration == pytest.approx(coefs, rel=1e-12)


@pytest.mark.parametrize("formula,says", [
    ("E = 5 + 2.4*c + 0.1*x^2", "two variables"),
    ("E = 5 + 2.4*c + 1.0*c", "appears twice"),
    ("E = 5 + 2.4*log(c)", "not a polynomial"),
])
def test_a_calibration_formula_that_is_not_a_polynomial_is_refused_naming_the_line(tmp_path, formula, says):
    f = tmp_path / "s.csv"
    f.write_text(f"# calibration: {formula}\n# live_time_s: 10\nchannel,counts\n0,1\n1,2\n2,3\n")
    with pytest.raises(SpectrumFileError, match=rf"s\.csv: # calibration:: .*{says}"):
        read_spectrum(f)


def test_bremsstrahlung_of_the_sources_betas_follows_kramers_thick_target_law():
    """``brems:U-nat``: the photons of Pa-234m's, Th-234's and Th-231's betas stopping in the source. Kramers'
    thick-target law puts (T - k)/k photons per unit k under each electron of energy T: nothing above the highest
    endpoint (Pa-234m, 2.27 MeV), and fewer photons at every higher energy."""
    import pydecay

    from spectra import bremsstrahlung

    e, y = np.array(bremsstrahlung.lines(FRESH_URANIUM)).T
    assert y.sum() == pytest.approx(1.0, rel=1e-9)
    end = max(pydecay.beta_spectrum(n)[0][-1] for n in ("Pa-234m", "Th-234")) * 1000.0
    assert e.max() - bremsstrahlung.STEP_KEV / 2 < end
    assert np.all(np.diff(y) < 0)
    with pytest.raises(ValueError, match="no beta emitter"):
        bremsstrahlung.lines("Am-241")  # an alpha emitter: no bremsstrahlung of its own


@pytest.mark.slow  # two real spectra evaluated and two predicted (no fit): tens of seconds on a busy machine
def test_rc103_saved_response_predicts_its_other_sources_as_the_benchmark_measured(capsys):
    """``radseek calibrate Am=Am-241 Th=Th-232 --detector rc103-006489.joint.detector.json --no-fit --predict ...``:
    the unit's saved response (``python -m benchmarks.real_spectra --unit rc103-006489``) gives the predicted
    distances the benchmark recorded in it, and the radium source's is half the emulator's response's or less."""
    import json

    from radseek_cli.main import main

    det = Path(__file__).resolve().parents[1] / "docs" / "img" / "rc103-006489.joint.detector.json"
    recorded = json.loads(det.read_text())["fit"]["predicted"]
    rc = main(["calibrate", f"{RC103 / 'Am-241_energy_calibrated.csv'}=Am-241",
               f"{RC103 / 'Th-232_energy_calibrated.csv'}=Th-232", "--detector", str(det), "--no-fit",
               "--predict", f"{RC103 / 'Ra-226_energy_calibrated.csv'}=Ra-226",
               "--predict", f"{RC103 / 'U-238-U-235-FiestaWare_energy_calibrated.csv'}=U-nat", "--json"])
    assert rc == 0
    r = json.loads(capsys.readouterr().out)
    got = {Path(sp["spectrum"]).name: sp for sp in r["predicted"]}
    for name, tv in recorded.items():
        assert got[name]["total_variation_32"] == pytest.approx(tv, abs=0.003), name
    ra = got["Ra-226_energy_calibrated.csv"]
    assert ra["total_variation_32"] <= 0.5 * ra["baseline"]["total_variation_32"]
