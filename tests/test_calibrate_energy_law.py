"""The energy law from a background's natural lines (spectra.energy_law): the series come from pydecay, a synthetic
background drawn with a known offset gives it back within its error, and the real 1800 s RadiaCode background is
reported as too weak to identify it (so calibrate keeps the gain-only law)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from pydecay.nuclide import Nuclide

from detector_fw_sim.response import gamma_lines
from radseek_io import spectrum_io as sf
from spectra import energy_law as EL
from spectra import model as M

DATA = Path(__file__).resolve().parent / "data" / "real-spectra"
CAL = (-6.38, 2.366, 4.4e-4)  # a RadiaCode-like 1024-channel calibration
REF = 661.657


def _response() -> dict[str, float]:
    p = M.baseline_params()
    p.update(gain=0.994, fwhm_at_662=0.10, fwhm_exponent=0.45)
    return p


def test_series_lines_follow_the_library_chain():
    ra = dict(EL.series_lines("Ra-226"))
    for e, y in gamma_lines("Bi-214"):  # Ra-226 -> Rn-222 -> Po-218 -> Pb-214 -> Bi-214, all branches ~1
        if y >= EL.MIN_LINE_YIELD:
            assert ra[e] == pytest.approx(y, rel=2e-3)
    assert max(e for e in ra) < 2500  # stops at Pb-210 (22 y): no line of the longer-lived tail
    th = dict(EL.series_lines("Th-228"))
    bi212 = Nuclide.load("Bi-212")
    to_tl = dict(zip(bi212.progeny, bi212.branching, strict=False))["Tl-208"]
    tl = dict(gamma_lines("Tl-208"))
    e2614 = max(tl)
    assert th[e2614] == pytest.approx(to_tl * tl[e2614], rel=1e-6)


@pytest.mark.parametrize("true_offset", [2.5, -1.5])
def test_synthetic_background_gives_back_its_energy_law(true_offset):
    """A background drawn from the model with a known law (offset, and the gain that keeps 662 keV where the source
    fit put it) returns both within 4 sigma, and the offset counts as identified."""
    p = _response()
    b = sf.Spectrum(np.ones(1024), 1800.0, calibration=CAL).edges_keV()
    ref_file = p["gain"] * REF
    amps = {k: 2.0e4 for k in EL.SERIES_HEADS}
    cont = np.array([np.log(0.5), -1.5, 0.1, 0.0, 0.0])  # counts per keV at 662 keV, falling with E
    centre = 0.5 * (b[1:] + b[:-1])
    lam = EL.background_model(b, true_offset, cont, amps, p, REF, ref_file) * (centre >= 100)
    n = np.random.default_rng(11).poisson(lam).astype(float)
    r = EL.fit_background_offset(sf.Spectrum(n, 1800.0, calibration=CAL), p, REF)
    assert r.identified, r.as_dict()
    assert abs(r.offset_keV - true_offset) < 4 * r.offset_error_keV, r.as_dict()
    true_gain = (ref_file - true_offset) / REF
    assert abs(r.gain - true_gain) < 4 * r.offset_error_keV / REF
    assert 0.7 < r.deviance_per_dof < 1.3  # the model is the truth


def test_real_background_is_too_weak_for_the_offset():
    """bg.xml (1800 s, 9481 counts): no series is detected at 3 sigma, so the offset is not identified."""
    p = _response()
    r = EL.fit_background_offset(sf.read_spectrum(DATA / "bg.xml"), p, REF)
    assert not r.identified
    for s in r.series.values():
        assert s["decays"] < 3 * s["error"]


def test_background_outside_the_fitted_range_says_nothing():
    """A background calibrated to 0-120 keV (or empty) has no natural line in 150-2800 keV: not identified, no error."""
    p = _response()
    low = sf.Spectrum(np.full(1024, 5.0), 1800.0, calibration=(0.0, 0.117))
    empty = sf.Spectrum(np.zeros(1024), 1800.0, calibration=CAL)
    for bg in (low, empty):
        r = EL.fit_background_offset(bg, p, REF)
        assert not r.identified and not np.isfinite(r.offset_error_keV)
        d = r.as_dict()
        assert d["identified"] is False and d["offset_error_keV"] is None
        json.dumps(d, allow_nan=False)  # strict JSON


@pytest.mark.slow  # a whole calibration fit (7-15 s a worker): make test, not make check
def test_calibrate_reports_the_energy_law(tmp_path):
    from radseek_cli.calibrate_cli import run

    r = run(str(DATA / "Cs137_b.xml"), ["Cs-137"], str(DATA / "bg.xml"), effects=["resolution_law"])
    el = r["energy_law"]
    assert el is not None and el["applied"] is False and "why" in el
    assert el["reference_keV"] == pytest.approx(REF)
    assert r["parameters"]["offset_keV"] == 0.0  # not identified: the law stays gain-only
