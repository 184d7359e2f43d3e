"""radseek calibrate's joint form (issue 32): natural chains from the library, one response fitted to several real
spectra of one unit, no-refit predictions of the same unit's other sources, --out that never replaces a file without
--force, and no NaN in what it writes; the single-spectrum form gives the figures it gave before."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from radseek.detector_file import DetectorFile, DetectorFileError, read_detector_file
from radseek.photon_lines import equilibrium_lines, gamma_lines, source_lines
from spectra import calibrate_cli as C

DATA = Path(__file__).resolve().parent / "data" / "real-spectra"


def _line(lines, energy_keV: float) -> float:
    """Photons per decay of the head at ``energy_keV`` (+-0.1 keV)."""
    return sum(y for e, y in lines if abs(e - energy_keV) < 0.1)


@pytest.mark.parametrize("head,energy,ensdf,rel", [
    # ENSDF (NNDC) intensities per decay of the head in secular equilibrium; pydecay's ICRP-107 tables are older
    # evaluations: Tl-208 2614.5 keV is 99.16 % there against 99.75 % in ENSDF (x 0.3594, the Bi-212 -> Tl-208 branch)
    ("Th-232", 2614.51, 0.3585, 0.01),
    ("Th-232", 583.19, 0.3055, 0.01),   # Tl-208 85.0 % x 0.3594
    ("Th-232", 911.20, 0.258, 0.01),    # Ac-228
    ("Th-232", 238.63, 0.436, 0.01),    # Pb-212
    ("U-238", 1001.03, 0.00842, 0.03),  # Pa-234m (short-lived, under Th-234)
    ("U-238", 609.31, 0.4549, 0.015),   # Bi-214, through U-234, Th-230 and Ra-226
    ("U-238", 1764.49, 0.1531, 0.01),
    ("Ra-226", 351.93, 0.356, 0.06),    # Pb-214 (ENSDF 35.60 %; ICRP-107 37.6 %)
    ("U-235", 185.72, 0.572, 0.01),
    ("K-40", 1460.82, 0.1066, 0.005),
])
def test_natural_chain_lines_come_from_the_library(head, energy, ensdf, rel):
    assert _line(source_lines(head), energy) == pytest.approx(ensdf, rel=rel)


def test_chain_walk_reaches_the_long_lived_members_only_for_chain_heads():
    th = dict(equilibrium_lines("Th-232"))
    assert _line(gamma_lines("Th-232"), 2614.51) == 0  # the nuclide alone: no Tl-208
    assert _line(th.items(), 2614.51) > 0.35
    # equilibrium: every member decays at the head's rate x its branching, so Ac-228 (under Ra-228, 5.75 y) counts
    # with the same weight as in the nuclide's own table
    for e, y in gamma_lines("Ac-228"):
        if y >= 0.05:
            assert th[e] == pytest.approx(y, rel=1e-6)
    assert source_lines("Cs-137") == gamma_lines("Cs-137")  # any other nuclide: unchanged
    with pytest.raises(ValueError, match="Xx-999"):
        source_lines("Xx-999")


def test_out_never_replaces_a_file_without_force(tmp_path, capsys):
    """--out refuses an existing file before any work (the rule of ``radseek run`` / ``simulate-dataset``, through
    ``radseek.outdir.check_output_file``), in both forms; with --force the file is replaced by a valid one."""
    from radseek.cli import main

    out = tmp_path / "det.json"
    out.write_text("an earlier calibration\n")
    cs, bg = str(DATA / "Cs137_b.xml"), str(DATA / "bg.xml")
    for argv in (["calibrate", cs, "--nuclide", "Cs-137", "--out", str(out)],
                 ["calibrate", f"{cs}=Cs-137", f"{DATA / 'Eu152_b.xml'}=Eu-152", "--out", str(out)]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert str(out) in err and "--force" in err
        assert out.read_text() == "an earlier calibration\n"
    rc = main(["calibrate", f"{cs}=Cs-137", "--background", bg, "--effects", "energy_calibration", "--out", str(out),
               "--force", "--json"])
    assert rc == 0
    r = json.loads(capsys.readouterr().out)
    det = read_detector_file(out)
    assert det.calibrated_on["spectra"][0]["nuclides"] == ["Cs-137"]
    assert det.fit["per_spectrum"]["Cs137_b.xml"] == r["spectra"][0]["total_variation_32"]
    assert not list(tmp_path.glob(".tmp-*"))  # the atomic write left no temporary behind


def test_no_nan_is_ever_written(tmp_path):
    det = DetectorFile(name="x", parameters={"fwhm_at_662": 0.1, "gain": float("nan")},
                       fit={"total_variation_32": 0.03})
    with pytest.raises(DetectorFileError, match="parameters.gain"):
        det.write(tmp_path / "d.json")
    assert not (tmp_path / "d.json").exists()
    det.parameters["gain"] = 1.0
    det.fit["per_spectrum"] = {"a.xml": float("inf")}
    with pytest.raises(DetectorFileError, match=r"fit.per_spectrum.a.xml"):
        det.write(tmp_path / "d.json")
    with pytest.raises(ValueError, match=r"spectra\[1\].total_variation_32"):
        C.refuse_non_finite({"spectra": [{"total_variation_32": 0.1}, {"total_variation_32": math.nan}]})
    C.refuse_non_finite({"spectra": [{"total_variation_32": 0.1}], "x": np.float64(2.0), "n": None})


def test_joint_form_arguments_are_checked(capsys):
    from radseek.cli import main

    cs = str(DATA / "Cs137_b.xml")
    for argv, msg in ((["calibrate", f"{cs}=Cs-137", "--nuclide", "Cs-137"], "not both"),
                      (["calibrate", cs, cs], "joint form"),
                      (["calibrate", cs, "--nuclide", "Cs-137", "--drift"], "joint form")):
        with pytest.raises(SystemExit):
            main(argv)
        assert msg in capsys.readouterr().err
    assert main(["calibrate", f"{cs}=Xx-999"]) == 2
    assert "Xx-999" in capsys.readouterr().err
    assert C.parse_pair("a=b.xml=Th-232,K-40") == ("a=b.xml", ["Th-232", "K-40"])
    with pytest.raises(ValueError, match="FILE=NUCLIDE"):
        C.parse_pair("Cs137.xml=")
