"""Spectral response physics: library data, Klein-Nishina, peaks and edges in the right channels."""

from __future__ import annotations

import numpy as np
import pytest

from detector_fw_sim import response
from detector_fw_sim.ladder import REFERENCE_EDGES_KEV

EDGES = np.array(REFERENCE_EDGES_KEV)
CRYSTAL = response.Crystal()


def channel_of(e_keV: float) -> int:
    return int(np.searchsorted(EDGES, e_keV, side="right") - 1)


def nuclide_fractions(nuclide: str, backscatter: float = 0.05) -> np.ndarray:
    lines = response.nuclide_response(nuclide, CRYSTAL, 0.07, backscatter)
    f = sum(r.photons_per_decay * r.fractions(EDGES) for r in lines)
    return f / f.sum()


def test_gamma_lines_come_from_the_library_through_the_daughter():
    lines = dict(response.gamma_lines("Cs-137"))
    # 0.944 branching to Ba-137m times 0.8974 photons per Ba-137m decay (ICRP-107)
    assert lines[661.657] == pytest.approx(0.94399 * 0.897393, rel=1e-6)
    co = dict(response.gamma_lines("Co-60"))
    assert co[1173.23] == pytest.approx(0.9985, rel=1e-4) and co[1332.49] == pytest.approx(0.9998, rel=1e-3)
    assert response.main_line_keV("Cs-137") == pytest.approx(661.657)
    with pytest.raises(ValueError, match="Xx-999"):
        response.gamma_lines("Xx-999")


def test_attenuation_coefficients_match_published_values():
    # NIST XCOM (shared/notes/verified-facts.md): air 0.0771 cm^2/g -> 0.0093 /m; concrete 2.3 g/cm^3 ~ 18 /m;
    # CsI 0.0775 cm^2/g at 662 keV. Our CsI is built from Klein-Nishina + Z-scaled lead photoabsorption.
    assert response.mu_per_m("air", 661.657) == pytest.approx(0.0093, rel=0.02)
    assert response.mu_per_m("concrete", 661.657) == pytest.approx(18.1, rel=0.02)
    assert response.csi_mu_over_rho(661.657) == pytest.approx(0.0775, rel=0.03)
    # photoabsorption dominates at low energy, Compton at high energy (crossover in CsI near 250-300 keV)
    p, c = response.csi_coefficients(100.0)
    assert p > 5 * c
    p, c = response.csi_coefficients(1332.0)
    assert c > 5 * p
    # a cinder block (60 % voids) attenuates less than solid concrete, linearly in the solid share
    assert response.mu_per_m("concrete", 661.657, 2.3, 0.6) == pytest.approx(0.4 * response.mu_per_m("concrete",
                                                                                                      661.657))


def test_klein_nishina_is_self_consistent():
    e = 661.657
    # the analytic total equals both differential forms integrated (independent formulas)
    t = np.linspace(0, response.compton_edge_keV(e), 200_001)
    assert np.trapezoid(response.klein_nishina_dT(e, t), t) == pytest.approx(response.klein_nishina_total(e), rel=1e-6)
    th = np.linspace(0, np.pi, 200_001)
    integral = np.trapezoid(response.klein_nishina_dOmega(e, th) * 2 * np.pi * np.sin(th), th)
    assert integral == pytest.approx(response.klein_nishina_total(e), rel=1e-6)
    # Thomson limit at low energy: 8/3 pi r_e^2 = 0.6652 barn; 0.2562 barn at 662 keV
    assert response.klein_nishina_total(0.01) == pytest.approx(0.6652e-24, rel=1e-3)
    assert response.klein_nishina_total(e) == pytest.approx(0.2562e-24, rel=1e-3)
    assert response.compton_edge_keV(e) == pytest.approx(477.3, abs=0.2)
    assert float(response.scattered_energy_keV(e, np.pi)) == pytest.approx(184.3, abs=0.2)


def test_cs137_photopeak_and_compton_edge_land_where_physics_puts_them():
    frac = nuclide_fractions("Cs-137")
    assert frac.sum() == pytest.approx(1.0)
    peak = channel_of(661.657)
    assert peak == 13
    # the photopeak channel is the fullest above the backscatter region
    assert int(np.argmax(frac[6:])) + 6 == peak
    # Compton edge: the steepest fall of the fine spectrum between 300 and 600 keV is at 477 keV
    # (within the resolution, sigma = 17 keV there)
    lr = response.line_response(661.657, 1.0, CRYSTAL, 0.07, 0.0)
    spec = np.diff(lr.cdf)
    grid = response.energy_grid()
    centres = 0.5 * (grid[1:] + grid[:-1])
    window = (centres > 300) & (centres < 600)
    steepest = centres[window][np.argmin(np.gradient(spec)[window])]
    assert steepest == pytest.approx(477.3, abs=17)
    # ... and in channels: the largest drop between neighbouring channels below the peak is across it
    drops = frac[5:12] - frac[6:13]
    assert 5 + int(np.argmax(drops)) == channel_of(477.3)
    # resolution: FWHM of the photopeak ~7 % of 662 keV (2 keV grid: allow 10 %)
    pk = centres > 560
    sp = np.where(pk, spec, 0.0)
    above = centres[sp > sp.max() / 2]
    assert (above.max() - above.min() + response.GRID_STEP_KEV) / 661.657 == pytest.approx(0.07, rel=0.1)


def test_backscatter_peak_and_co60_lines():
    cs_with = nuclide_fractions("Cs-137", 0.05)
    cs_without = nuclide_fractions("Cs-137", 0.0)
    bs = channel_of(184.3)
    assert cs_with[bs] > 1.5 * cs_without[bs]  # the backscatter bump is where 180 deg scatter puts it
    co = nuclide_fractions("Co-60")
    p1, p2 = channel_of(1173.23), channel_of(1332.49)
    assert co[p1] > co[p1 - 2] and co[p1] > co[p1 + 2]
    assert co[p2] > co[p2 - 2] and co[p2] > co[p2 + 2]
    assert co[p2 + 3:].sum() < 0.01  # nothing much above 1.33 MeV (pair production and sums are neglected)


def test_activity_conversion_uses_efficiency_and_face_area():
    one = response.cps_at_1m_from_activity(1.0, "Cs-137", CRYSTAL, 0.07, 0.05, EDGES)
    assert response.cps_at_1m_from_activity(10.0, "Cs-137", CRYSTAL, 0.07, 0.05, EDGES) == pytest.approx(10 * one)
    # bound by the geometry alone: 0.847 photons/decay * face / (4 pi m^2) * (P_counted <= 1)
    geometric = 1e6 * 0.8471 * CRYSTAL.face_area_m2 / (4 * np.pi)
    assert 0.2 * geometric < one < geometric
    # a 1 cm CsI crystal stops 1 - exp(-mu L) ~ 30 % of 662 keV photons; those counted are fewer by the
    # single Compton scatters depositing < 40 keV (the first threshold) whose photon escapes
    mu = sum(response.csi_coefficients(661.657))
    p_int = 1 - np.exp(-mu * 1.0)
    counted = response.nuclide_response("Cs-137", CRYSTAL, 0.07, 0.0)[-1].counted(EDGES)
    t = np.linspace(0, response.compton_edge_keV(661.657), 100_001)
    kn = response.klein_nishina_dT(661.657, t)
    below = np.trapezoid(np.where(t < 40.0, kn, 0.0), t) / np.trapezoid(kn, t)
    photo, compton = response.csi_coefficients(661.657)
    assert p_int * (1 - compton / mu * below) * 0.97 < counted <= p_int


def test_thick_scatter_share_scale_is_the_single_scattering_albedo_ratio():
    """``scatter_share_scale`` against scipy's adaptive quadrature of the albedo integrand written out here
    (Klein-Nishina in its textbook form, concrete mu/rho from pydecay): dsigma/dOmega sin(theta) over
    mu(E) + mu(E'), at the line energy over at 662 keV. It is 1 at the reference line and falls with energy at
    backward angles."""
    import math

    import pydecay
    from scipy.integrate import quad

    mat = pydecay.material(response.SCATTERER_MATERIAL)

    def integrand(theta, e):
        p = 1.0 / (1.0 + e / 510.99895 * (1.0 - math.cos(theta)))  # E'/E
        dsig = 0.5 * p**2 * (p + 1.0 / p - math.sin(theta) ** 2)  # r_e^2 left out: it cancels in the ratio
        return dsig * math.sin(theta) / (mat.mu_over_rho(e / 1000.0) + mat.mu_over_rho(e * p / 1000.0))

    def ratio(e, lo, hi):
        def y(en):
            return quad(integrand, math.radians(lo), math.radians(hi), args=(en,), limit=200)[0]
        return y(e) / y(response.SHARE_REFERENCE_KEV)

    for e, lo, hi in ((356.0, 110.0, 180.0), (81.0, 32.0, 110.0), (1332.5, 0.0, 180.0)):
        assert response.scatter_share_scale(e, lo, hi) == pytest.approx(ratio(e, lo, hi), rel=2e-3)
    assert response.scatter_share_scale(661.657, 110.0, 180.0) == pytest.approx(1.0)
    back = [response.scatter_share_scale(e, 110.0, 180.0) for e in (356.0, 661.657, 1173.2, 1332.5)]
    assert back == sorted(back, reverse=True) and back[0] > 1.2 and back[-1] < 0.8


def test_scatter_shares_are_given_at_662_kev_and_scaled_per_line():
    """Each component's share at a line energy is the 662 keV share times the thick-slab scale."""
    eff = response.ResponseEffects(scatter_side=0.1, scatter_multiple=0.04, side_scatter_min_deg=30.0)
    scale = response.scatter_share_scale
    for e in (121.8, 661.657, 1173.2):
        comps = response.scatter_components(e, 0.05, eff)
        want = [0.05 * scale(e, 110.0, 180.0), 0.1 * scale(e, 30.0, 110.0), 0.04 * scale(e, 0.0, 180.0)]
        assert [c[0] for c in comps] == pytest.approx(want, rel=1e-12)


def test_the_deposit_histogram_is_numpys_bit_for_bit():
    """``response._histogram`` (a stable sort where numpy's histogram uses quicksort) gives np.histogram's numbers
    bit for bit: on a line's Compton deposits (sorted runs, as ``deposit_parts`` makes them), on values with ties,
    values off the grid and on its edges, and past numpy's block of 65,536 values."""
    rng = np.random.default_rng(7)
    edges = response.energy_grid()
    t = np.linspace(0.0, 477.0, 200)
    runs = (rng.uniform(0.0, 200.0, 200)[:, None] + t[None, :] * rng.uniform(0.5, 1.0, 200)[:, None]).ravel()
    ties = np.round(rng.uniform(0.0, 4000.0, 5000))
    off = np.concatenate([rng.uniform(-100.0, 4100.0, 3000), [0.0, 2.0, 3998.0, 4000.0, 4000.5]])
    for values in (runs, ties, off, rng.uniform(0.0, 4000.0, 70_000)):
        weights = rng.uniform(0.0, 1e-3, len(values))
        ours = response._histogram(values, weights, edges)
        numpys = np.histogram(values, bins=edges, weights=weights)[0]
        assert np.array_equal(ours, numpys) and np.array_equal(np.signbit(ours), np.signbit(numpys))


@pytest.mark.parametrize(("fwhm", "exponent"),
                         [(0.07, 0.5), (0.126626, 0.562612), (0.3, 0.2), (0.02, 0.8), (1e-4, 0.5)])
def test_the_resolution_matrix_is_erf_over_every_edge_bit_for_bit(fwhm, exponent):
    """``_resolution_matrix`` evaluates erf only near each row's centre: the same matrix as erf over all edges."""
    import math

    from scipy.special import erf

    edges = response.energy_grid()
    centres = 0.5 * (edges[1:] + edges[:-1])
    sigma = np.maximum(response.fwhm_keV(centres, fwhm, exponent) / (2 * math.sqrt(2 * math.log(2))),
                       response.GRID_STEP_KEV / 2)
    dense = np.diff(0.5 * (1 + erf((edges[None, :] - centres[:, None]) / (sigma[:, None] * math.sqrt(2)))), axis=1)
    assert np.array_equal(response._resolution_matrix.__wrapped__(fwhm, exponent), dense)
