"""True coincidence summing of a cascade (``spectra.coincidence`` and the ``coincidence_summing`` response effect):
the analytic two-photon case, the sum peak at E1 + E2 with the analytic area ratio in the response, the cascade
found from the library's yields only, and on the real RC-102 Co-60 spectrum what the data say about it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from detector_fw_sim import response
from radseek.photon_lines import source_lines
from spectra import coincidence as C
from spectra import fit as F
from spectra import model as M

DATA = Path(__file__).resolve().parent / "data" / "real-spectra"
DOCS = Path(__file__).resolve().parents[1] / "docs" / "img"


def test_two_photon_summing_analytic():
    # eps_t = 0.1 / 0.08 total, eps_p = 0.03 / 0.02 photopeak: each peak loses the partner's total efficiency
    p1, p2, s = C.two_photon_summing(0.03, 0.1, 0.02, 0.08)
    assert p1 == pytest.approx(0.03 * 0.92)
    assert p2 == pytest.approx(0.02 * 0.90)
    assert s == pytest.approx(0.03 * 0.02)
    assert s / p2 == pytest.approx(0.03 / 0.90)  # sum/peak-2 = eps_p1 / (1 - eps_t1)
    with pytest.raises(ValueError, match="eps_p1"):
        C.two_photon_summing(1.5, 0.1, 0.02, 0.08)
    with pytest.raises(ValueError, match="exceed"):
        C.two_photon_summing(0.2, 0.1, 0.02, 0.08)


def test_solid_angle_of_a_disc_on_its_axis():
    assert C.solid_angle_fraction(0.0, 5.0) == pytest.approx(0.5)
    assert C.solid_angle_fraction(5.0, 5.0) == pytest.approx(0.5 * (1 - 1 / math.sqrt(2)))
    # far away: pi R^2 / (4 pi d^2)
    assert C.solid_angle_fraction(1000.0, 5.0) == pytest.approx(25 / (4 * 1000.0**2), rel=1e-3)
    with pytest.raises(ValueError, match="distance"):
        C.solid_angle_fraction(-1.0, 5.0)


def test_cascades_come_from_the_library_yields_within_one_nuclide():
    (e1, y1), (e2, y2) = source_lines("Co-60")
    assert M.cascade_pairs(("Co-60",)) == ((0, 1, pytest.approx(y1 + y2 - 1)),)
    assert y1 + y2 - 1 > 0.99 and abs(e1 + e2 - 2505.7) < 0.1  # the Ni-60 2505.7 keV level
    assert M.cascade_pairs(("Cs-137",)) == () and M.cascade_pairs(("Eu-152",)) == ()
    # Cs-137's 662 keV (0.85) with Co-60's lines would pass y1 + y2 - 1 > 0.5: never paired across nuclides
    n_cs = len(source_lines("Cs-137"))
    assert [(i, j) for i, j, _ in M.cascade_pairs(("Cs-137", "Co-60"))] == [(n_cs, n_cs + 1)]


def _bare(distance_mm: float) -> dict[str, float]:
    """The response with nothing scattered outside the crystal, no pile-up: every photon reaches the crystal."""
    return dict(M.baseline_params(), backscatter_fraction=0.0, pileup=0.0, source_distance_mm=distance_mm)


def test_sum_peak_at_2505_keV_with_the_analytic_area_ratio():
    d = 5.0
    q = _bare(d)
    e, w, _ = M.deposited(q, ("Co-60",))
    (e1, y1), (e2, y2) = source_lines("Co-60")
    c = y1 + y2 - 1
    crystal = M.crystal_of(q)

    def eff(energy):  # intrinsic full-energy and total interaction probability, from the crystal transport
        peaks, cont = response.deposit_parts(energy, crystal)
        full = sum(pw for pe, pw in peaks if abs(pe - energy) < 1e-6)
        return full, sum(pw for _, pw in peaks) + cont.sum()

    (p1, t1), (p2, t2) = eff(e1), eff(e2)
    g = C.solid_angle_fraction(d, q["crystal_mm"] / 2)
    at = lambda energy: w[np.abs(e - energy) < 1e-6].sum()  # noqa: E731
    sum_peak = at(e1 + e2)
    assert sum_peak > 0 and abs(e1 + e2 - 2505.72) < 0.01
    # per photon reaching the crystal (the amplitude holds g): sum / peak 2 = c g P1 P2 / ((y2 - c g T1) P2)
    expected = C.two_photon_summing(g * p1, g * t1, g * p2, g * t2)
    assert sum_peak / at(e2) == pytest.approx(expected[2] / expected[1], rel=0.003)  # c = 0.998, not 1
    assert sum_peak / at(e2) == pytest.approx(c * g * p1 / (y2 - c * g * t1), rel=1e-9)
    # summing-out: each photopeak loses the partner's total efficiency
    e0, w0, _ = M.deposited(_bare(M.NO_SUMMING_MM), ("Co-60",))
    before = lambda energy: w0[np.abs(e0 - energy) < 1e-6].sum()  # noqa: E731
    assert at(e1) / before(e1) == pytest.approx(1 - c * g * t2 / y1, rel=1e-9)
    assert at(e2) / before(e2) == pytest.approx(1 - c * g * t1 / y2, rel=1e-9)
    # two deposits become one pulse: the recorded events fall by exactly c g T1 T2 per decay
    assert w0.sum() - w.sum() == pytest.approx(c * g * t1 * t2, rel=1e-6)
    # no event above E1 + E2
    assert e[w > 0].max() <= e1 + e2 + 1e-6


def test_summing_off_at_the_baseline_and_for_cs137():
    q = _bare(M.NO_SUMMING_MM)
    e0, w0, _ = M.deposited({k: v for k, v in q.items() if k != "source_distance_mm"}, ("Co-60",))
    e1, w1, _ = M.deposited(q, ("Co-60",))
    assert np.array_equal(e0, e1) and np.array_equal(w0, w1)
    e2, w2, _ = M.deposited(_bare(3.0), ("Cs-137",))
    assert np.array_equal(w2, M.deposited(q, ("Cs-137",))[1])


def test_summing_grows_as_the_source_nears_the_crystal():
    edges = np.arange(50.0, 3000.0, 3.0)
    high = [(s := M.native_shape(_bare(d), ("Co-60",), edges))[edges[:-1] > 1600].sum() / s.sum()
            for d in (100.0, 20.0, 5.0)]
    assert high[0] < high[1] < high[2]


@pytest.mark.slow
def test_real_co60_holds_no_summing_the_fit_moves_the_source_away():
    """RC-102-001272's Co-60 with the saved joint response: 1 count in 2420-2600 keV; freeing the distance, the
    likelihood pushes the source beyond 60 mm (summing within 5 % of the no-summing deviance at 60 mm: +0.7)."""
    from radseek_io.detector_file import read_detector_file
    from radseek_io.spectrum_io import read_spectrum

    det = read_detector_file(DOCS / "rc102-001272.joint.detector.json")
    p = M.baseline_params()
    p.update({k: v for k, v in det.parameters.items() if k in M.PARAMS})
    pr = F.Problem(read_spectrum(DATA / "Co60_a.xml"), ("Co-60",), read_spectrum(DATA / "bg.xml"))
    p["pileup"] = 2 * pr.rate_cps * det.parameters["pileup_resolving_time_s"]
    assert F.identifiable("coincidence_summing", pr)
    r0 = F.evaluate(pr, p)
    r10 = F.evaluate(pr, dict(p, source_distance_mm=10.0))
    assert r10.deviance - r0.deviance > 20  # 10 mm would put ~35 more counts above 1600 keV than pile-up does
    res = F.fit(pr, dict(p, source_distance_mm=30.0), ("coincidence_summing",), hesse=False)
    assert res.params["source_distance_mm"] > 60.0
    assert res.deviance <= r0.deviance + 0.5
