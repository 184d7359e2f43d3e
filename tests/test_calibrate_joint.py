"""radseek calibrate's joint form (issue 32): natural chains from the library, one response fitted to several real
spectra of one unit, no-refit predictions of the same unit's other sources, --out that never replaces a file without
--force, and no NaN in what it writes; the single-spectrum form gives the figures it gave before."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from radseek.photon_lines import equilibrium_lines, gamma_lines, source_lines
from radseek_cli import calibrate_cli as C
from radseek_io.detector_file import DetectorFile, DetectorFileError, read_detector_file
from tests.support.once_per_run import once_per_run

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
    ``radseek_io.outdir.check_output_file``), in both forms; with --force the file is replaced by a valid one."""
    from radseek_cli.main import main

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


def test_calibrate_reads_a_csv_without_live_time_given_live_time(tmp_path, capsys):
    """Cs137_b.xml's counts and calibration as a CSV that states no live time: calibrate refuses it naming
    --live-time, and with --live-time 300 gives the XML's figures (the saved response, no refit)."""
    from radseek_cli.main import main
    from radseek_io.spectrum_io import read_spectrum

    sp = read_spectrum(DATA / "Cs137_b.xml")
    csv = tmp_path / "cs137.csv"
    csv.write_text("# calibration: " + " ".join(f"{c!r}" for c in sp.calibration) + "\nchannel,counts\n"
                   + "".join(f"{i},{int(c)}\n" for i, c in enumerate(sp.counts)))
    args = ["calibrate", "--nuclide", "Cs-137", "--background", str(DATA / "bg.xml"), "--detector", str(JOINT_DET),
            "--no-fit", "--json"]
    assert main([*args, str(csv)]) == 2
    err = capsys.readouterr().err
    assert str(csv) in err and "--live-time" in err
    assert main([*args, str(DATA / "Cs137_b.xml")]) == 0
    want = json.loads(capsys.readouterr().out)
    assert main([*args, str(csv), "--live-time", "300"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["live_time_s"] == 300
    assert got["total_variation_32"] == pytest.approx(want["total_variation_32"], abs=1e-9)


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
    from radseek_cli.main import main

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


def test_drift_of_a_later_session_is_recovered():
    """Two spectra of one unit drawn from the model, the second read with its gain 3 % higher and its offset 2 keV
    higher (a session days later): the joint fit with --drift gives both back within 4 sigma, with the shared
    response held; the pile-up share a spectrum sees follows its rate (one resolving time)."""
    from radseek_io import spectrum_io as sf
    from spectra import fit as F
    from spectra import model as M

    cal = (-6.0, 4.8, 1.6e-3)  # 512 channels to 3 MeV: a small configuration
    p = M.baseline_params()
    p.update(fwhm_at_662=0.10)
    rng = np.random.default_rng(11)
    parts = []
    for nuc, gain, off, total in (("Cs-137", 1.0, 0.0, 2e5), ("Co-60", 1.03, 2.0, 1e5)):
        q = dict(p, gain=gain, offset_keV=off)
        prob0 = F.Problem(sf.Spectrum(np.ones(512), 300.0, calibration=cal), (nuc,))
        shape = prob0.shape(q)
        parts.append(F.Problem(sf.Spectrum(rng.poisson(total * shape / shape.sum()).astype(float), 300.0,
                                           calibration=cal), (nuc,)))
    joint = F.Joint(tuple(parts), drift=True)
    assert joint.drift_params() == ("gain_drift_1", "offset_drift_keV_1")
    seen = joint.part_params(dict(p, pileup=0.01, gain_drift_1=1.03, offset_drift_keV_1=2.0), 1)
    assert seen["gain"] == pytest.approx(1.03) and seen["offset_keV"] == pytest.approx(2.0)
    assert seen["pileup"] == pytest.approx(0.01 * parts[1].rate_cps / parts[0].rate_cps)
    res = F.fit(joint, p, ())
    for name, true in (("gain_drift_1", 1.03), ("offset_drift_keV_1", 2.0)):
        assert abs(res.params[name] - true) < 4 * res.errors[name], (name, res.params[name], res.errors[name])
    assert len(res.parts) == 2 and res.dof == sum(int(pr.mask.sum()) - 1 for pr in parts) - 2


def test_drift_of_one_spectrum_leaves_the_others_on_the_shared_law():
    """``Joint(drift=(2,))`` (``--drift-of K40.rcspg``): only that spectrum gets a gain and an offset; a same-day
    spectrum sees the shared law; an index that is not a spectrum after the first is refused."""
    from radseek_io import spectrum_io as sf
    from spectra import fit as F
    from spectra import model as M

    cal = (-6.0, 4.8, 1.6e-3)
    parts = tuple(F.Problem(sf.Spectrum(np.ones(512), 300.0, calibration=cal), (n,))
                  for n in ("Cs-137", "Eu-152", "K-40"))
    joint = F.Joint(parts, drift=(2,))
    assert joint.drift_params() == ("gain_drift_2", "offset_drift_keV_2")
    p = dict(M.baseline_params(), gain_drift_2=1.03, offset_drift_keV_2=-5.0)
    assert joint.part_params(p, 1)["gain"] == p["gain"] and joint.part_params(p, 1)["offset_keV"] == p["offset_keV"]
    assert joint.part_params(p, 2)["gain"] == pytest.approx(1.03 * p["gain"])
    assert F.Joint(parts, drift=True).drifting() == (1, 2)
    for bad in ((0,), (3,)):
        with pytest.raises(ValueError, match="drift indices"):
            F.Joint(parts, drift=bad)


def test_drift_of_arguments_are_checked(capsys):
    from radseek_cli.main import main

    cs, eu = f"{DATA / 'Cs137_b.xml'}=Cs-137", f"{DATA / 'Eu152_b.xml'}=Eu-152"
    for argv, msg in ((["calibrate", cs, eu, "--drift-of", "other.xml"], "not one of the fitted spectra"),
                      (["calibrate", cs, eu, "--drift-of", str(DATA / "Cs137_b.xml")], "not one of the fitted"),
                      (["calibrate", cs, eu, "--drift", "--drift-of", str(DATA / "Eu152_b.xml")], "not both")):
        with pytest.raises(SystemExit):
            main(argv)
        assert msg in capsys.readouterr().err


def test_overflow_channel_is_out_of_the_fit_and_the_distances():
    """K40.rcspg (sum of its 690 time rows) holds 1030 counts in its last channel, every pulse above the top edge:
    the fit and the shape distances leave that channel out (the XML spectra hold 0 there)."""
    from radseek_io.spectrum_io import read_spectrum
    from spectra import fit as F

    sp = read_spectrum(DATA / "K40.rcspg")
    assert sp.kind == "foreground" and sp.livetime == pytest.approx(43510.0) and sp.counts[-1] > 1000
    pr = F.Problem(sp, ("K-40",), read_spectrum(DATA / "bg.xml"))
    assert not pr.mask[-1] and pr.net()[-1] == 0
    assert pr.shape(F.M.baseline_params())[-1] == 0


REPO = Path(__file__).resolve().parents[1]
#: the joint calibration that ``python -m benchmarks.real_spectra`` writes (Cs137_b.xml + Eu152_b.xml, bg.xml): its
#: forward selection's nine effects, electron_escape the last
JOINT_DET = REPO / "docs" / "img" / "rc102-001272.joint.detector.json"
#: the benchmark's joint calibration before the selection re-scored an under-scored candidate: eight effects, no
#: electron escape (the start of the other units' refits)
NO_ESCAPE_DET = REPO / "docs" / "img" / "rc102-001272.joint-no-escape.detector.json"
CS_ONLY_DET = REPO / "docs" / "img" / "rc102-001272.detector.json"
#: TV32 measured by the benchmark (docs/real-spectra.md, "Figures per spectrum"): fitted, then no refit
MEASURED = {"Cs-137": 0.0260, "Eu-152": 0.0125, "Co-60": 0.0367, "Ba-133": 0.0108}
MARGIN = 0.003


@pytest.fixture(scope="module")
def joint_fit(tmp_path_factory):
    """The joint fit on the real Cs-137 + Eu-152 (+ bg.xml), in a small configuration: started from the saved joint
    response, the energy law (4 parameters) refitted with a short MIGRAD (the full forward selection from the
    emulator's response takes ~15 min: the benchmark). Once per run, whichever worker asks first."""
    from radseek_io.spectrum_io import read_spectrum
    from spectra import fit as F
    from spectra import model as M

    def fit_joint(_folder):
        bg = read_spectrum(DATA / "bg.xml")
        joint = F.Joint(tuple(F.Problem(read_spectrum(DATA / f), (n,), bg, name=f)
                              for f, n in (("Cs137_b.xml", "Cs-137"), ("Eu152_b.xml", "Eu-152"))))
        det = read_detector_file(JOINT_DET)
        start = {k: v for k, v in det.parameters.items() if k in M.PARAMS}
        start["pileup"] = 2 * joint.parts[0].rate_cps * det.parameters["pileup_resolving_time_s"]
        return joint, F.fit(joint, start, ("energy_nonlinearity",), maxfev=300, hesse=False)

    return once_per_run(tmp_path_factory, "joint-fit", fit_joint)


@pytest.mark.slow  # a whole calibration fit (7-15 s a worker): make test, not make check
def test_joint_fit_on_real_cs137_and_eu152_reaches_the_fitted_bound(joint_fit):
    from spectra import fit as F

    joint, res = joint_fit
    d = F.distances(joint, res)
    for (nuc, tv) in zip(("Cs-137", "Eu-152"), d["per_spectrum"], strict=True):
        assert tv <= 0.03, (nuc, tv)
        assert tv <= MEASURED[nuc] + MARGIN, (nuc, tv)
    assert res.deviance_per_dof < 1.6


@pytest.mark.slow  # a whole calibration fit (7-15 s a worker): make test, not make check
@pytest.mark.parametrize("name,nuclide", [("Co60_a.xml", "Co-60"), ("Ba133_a.xml", "Ba-133")])
def test_joint_response_predicts_co60_and_ba133_with_no_refit(joint_fit, name, nuclide):
    """The same unit's Co-60 and Ba-133, not in the fit: only the amplitude fitted (pile-up rescaled by rate). They
    meet the figures the benchmark measured, and beat the Cs-137-only response by far."""
    from radseek_io.spectrum_io import read_spectrum
    from spectra import fit as F

    joint, res = joint_fit
    bg = read_spectrum(DATA / "bg.xml")
    pr = F.Problem(read_spectrum(DATA / name), (nuclide,), bg)
    q = dict(res.params, pileup=res.params["pileup"] * pr.rate_cps / joint.parts[0].rate_cps)
    tv = F.shape_distances(pr, F.evaluate(pr, q).shape)["total_variation_32"]
    assert tv <= MEASURED[nuclide] + MARGIN
    cs_only = C.run(str(DATA / name), [nuclide], str(DATA / "bg.xml"), str(CS_ONLY_DET), True)
    assert tv < cs_only["total_variation_32"] - 0.01


def test_joint_cli_reports_each_spectrum_and_prediction(tmp_path, capsys):
    """The joint form end to end with the saved response (--no-fit): one entry per file in ``spectra`` and
    ``predicted``, each with its total_variation_32, strict JSON."""
    from radseek_cli.main import main

    rc = main(["calibrate", f"{DATA / 'Cs137_b.xml'}=Cs-137", f"{DATA / 'Eu152_b.xml'}=Eu-152",
               "--background", str(DATA / "bg.xml"), "--detector", str(JOINT_DET), "--no-fit",
               "--predict", f"{DATA / 'Co60_a.xml'}=Co-60", "--json"])
    assert rc == 0
    r = json.loads(capsys.readouterr().out)
    assert [sp["nuclides"] for sp in r["spectra"]] == [["Cs-137"], ["Eu-152"]]
    assert [sp["nuclides"] for sp in r["predicted"]] == [["Co-60"]]
    for sp in r["spectra"]:
        assert sp["total_variation_32"] <= MEASURED[sp["nuclides"][0]] + MARGIN
    assert r["predicted"][0]["total_variation_32"] <= MEASURED["Co-60"] + MARGIN
    assert {ln["line_keV"] for ln in r["predicted"][0]["lines"]} == {1173.23, 1332.49}


@pytest.mark.slow  # four spectra evaluated with two responses (~10 s)
def test_electron_escape_is_identified_on_the_calibration_pair_and_predicts_co60():
    """The escape factor is fitted on Cs-137 + Eu-152 only (the benchmark's forward selection chose it last): the
    joint deviance is more than 25 below the eight-effect response's for its one parameter (5 sigma), neither fitted
    spectrum passes 0.03, and Co-60 and Ba-133 with no refit meet 0.04 and
    improve on the response without it (Co-60 by more than 0.004)."""
    from radseek_io.spectrum_io import read_spectrum
    from spectra import fit as F
    from spectra import model as M

    bg = read_spectrum(DATA / "bg.xml")
    joint = F.Joint(tuple(F.Problem(read_spectrum(DATA / f), (n,), bg, name=f)
                          for f, n in (("Cs137_b.xml", "Cs-137"), ("Eu152_b.xml", "Eu-152"))))
    preds = [F.Problem(read_spectrum(DATA / f), (n,), bg) for f, n in (("Co60_a.xml", "Co-60"),
                                                                        ("Ba133_a.xml", "Ba-133"))]
    tv, dev = {}, {}
    for tag, path in (("without", NO_ESCAPE_DET), ("with", JOINT_DET)):
        det = read_detector_file(path)
        q = {k: v for k, v in det.parameters.items() if k in M.PARAMS}
        q["pileup"] = 2 * joint.parts[0].rate_cps * det.parameters["pileup_resolving_time_s"]
        res = F.evaluate(joint, q)
        dev[tag] = res.deviance
        tv[tag] = dict(zip(("Cs-137", "Eu-152"), F.distances(joint, res)["per_spectrum"], strict=True))
        for pr in preds:
            qp = dict(q, pileup=q["pileup"] * pr.rate_cps / joint.parts[0].rate_cps)
            tv[tag][pr.nuclides[0]] = F.shape_distances(pr, F.evaluate(pr, qp).shape)["total_variation_32"]
    f = read_detector_file(JOINT_DET).parameters["electron_range_factor"]
    assert 0.1 < f < 0.9  # a projected / CSDA range ratio, not a knob at its bound
    assert dev["without"] - dev["with"] > 25.0
    for nuc in ("Cs-137", "Eu-152"):
        assert tv["with"][nuc] <= 0.03, (nuc, tv)
    for nuc in ("Co-60", "Ba-133"):
        assert tv["with"][nuc] <= 0.04, (nuc, tv)
        assert tv["with"][nuc] < tv["without"][nuc], (nuc, tv)
    assert tv["with"]["Co-60"] < tv["without"]["Co-60"] - 0.004
    for nuc, measured in MEASURED.items():
        assert tv["with"][nuc] <= measured + MARGIN, (nuc, tv)
