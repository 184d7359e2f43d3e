"""A second RadiaCode unit (RC-102-013789, tests/data/real-spectra-rc102-013789, MIT): its app XML exports read as
an independent parse of the same files says, natural uranium without its daughters (uranium glass) as a calibration
source, and the joint response of this unit predicting its other sources with no refit (issue 32)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from radseek.photon_lines import FRESH_URANIUM, equilibrium_lines, natural_uranium_activity_ratio, source_lines
from radseek_io.spectrum_io import read_spectrum

DATA = Path(__file__).resolve().parent / "data" / "real-spectra-rc102-013789"
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
