"""The source's photons backscattered by material around it (spectra.surroundings), a per-measurement nuisance:
Compton kinematics and Klein-Nishina weights against quadrature, and its amplitude recovered from a seeded synthetic
spectrum beside a held response (spectra.fit.fit_with_component)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats
from scipy.integrate import quad

from detector_fw_sim import response
from radseek_io import spectrum_io as sf
from spectra import fit as F
from spectra import model as M
from spectra import surroundings as S

Z = 4.5  # sigma of every statistical bound
CS_LINE = 661.657


def _kn_weight(E: float, theta: float) -> float:
    return float(response.klein_nishina_dOmega(E, np.array([theta]))[0]) * math.sin(theta)


def test_backscattered_energies_follow_compton_kinematics_and_klein_nishina():
    """Cs-137's 662 keV photons scattered through 110-180 deg: every energy between E'(180 deg) = 184.3 keV and
    E'(110 deg), and their mean the Klein-Nishina-weighted mean of E'(theta) by quadrature (within 0.5 keV:
    24 angle nodes and 2 keV bins). The component is one photon in all."""
    lines = S.lines("Cs-137")
    e = np.array([x for x, _ in lines])
    w = np.array([y for _, y in lines])
    assert w.sum() == pytest.approx(1.0)
    sel = e > 100.0  # the 662 keV line's photons (the Ba K X-rays scatter to below 35 keV)
    lo = CS_LINE / (1 + 2 * CS_LINE / response.MEC2_KEV)
    hi = float(response.scattered_energy_keV(CS_LINE, math.radians(110.0)))
    assert lo == pytest.approx(184.3, abs=0.1)
    assert e[sel].min() >= lo - 1.0 and e[sel].max() <= hi + 1.0
    a, b = math.radians(110.0), math.pi
    num = quad(lambda t: float(response.scattered_energy_keV(CS_LINE, t)) * _kn_weight(CS_LINE, t), a, b)[0]
    den = quad(lambda t: _kn_weight(CS_LINE, t), a, b)[0]
    assert np.average(e[sel], weights=w[sel]) == pytest.approx(num / den, abs=0.5)


def _synthetic(extra_per_photon: float, seed: int, total: float = 1.0e6) -> tuple[F.Problem, dict[str, float]]:
    """A Cs-137 spectrum (RadiaCode-like calibration) drawn from a response plus ``extra_per_photon`` backscattered
    photons per line photon, and a flat background known to the fit."""
    p = dict(M.baseline_params(), fwhm_at_662=0.095, fwhm_exponent=0.42, scatter_side=0.08, gain=1.02)
    cal = (-6.0, 2.4, 4e-4)
    prob = F.Problem(sf.Spectrum(np.ones(1024), 300.0, calibration=cal), ("Cs-137",), None)
    lines = prob.shape(p)
    photons = sum(y for _, y in M.source_lines("Cs-137"))
    extra = F.Problem(prob.spectrum, (S.PREFIX + "Cs-137",), None).shape(S.component_params(p))
    mu = lines + extra_per_photon * photons * extra
    lam = total * mu / mu.sum() + 0.2
    sp = sf.Spectrum(np.random.default_rng(seed).poisson(lam).astype(float), 300.0, calibration=cal)
    bg = sf.Spectrum(np.full(1024, 0.2 * 6), 1800.0, calibration=cal)
    return F.Problem(sp, ("Cs-137",), bg), p


@pytest.mark.parametrize("extra", [0.0, 0.04])
def test_backscatter_amplitude_is_recovered_beside_a_held_response(extra):
    """Drawn with 0 or 0.04 backscattered photons per line photon: the fitted amplitude is the truth within Z of its
    Fisher error; with 0.04 the component removes more deviance than the chi-square 99.9 % point for one amplitude
    and lowers TV32, with 0 it removes less than the Z-sigma point."""
    prob, p = _synthetic(extra, seed=32 if extra else 33)
    r = F.fit_with_component(prob, p, S.PREFIX + "Cs-137", S.component_params(p))
    assert 0 < r["per_photon_error"] < 0.01
    assert abs(r["per_photon"] - extra) < Z * r["per_photon_error"], r
    if extra:
        assert r["deviance_drop"] > stats.chi2.isf(1e-3, 1)
        assert r["total_variation_32"] < r["total_variation_32_without"]
    else:
        assert r["deviance_drop"] < Z**2
