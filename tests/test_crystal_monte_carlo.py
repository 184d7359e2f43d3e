"""The crystal's deposited-energy response (``detector_fw_sim.response.deposit_parts``: analytic, up to two
Compton scatters, escape along the mean chord) against an independent forward model: a photon-by-photon
Monte Carlo through the same 10 x 10 mm CsI cylinder, with the exact geometry and every scatter followed,
from the same cross sections (XCOM via pydecay). Neither model has electron escape, Rayleigh scattering or
fluorescence."""

import numpy as np
import pytest

from detector_fw_sim import response

MEC2_KEV = 510.99895


def _kn_cosines(rng, k):
    """Klein-Nishina scattering cosines for photons of k = E / m_e c^2 (rejection: dsigma/dOmega <= its value at 0)."""
    cos = np.empty(k.size)
    todo = np.arange(k.size)
    while todo.size:
        m = rng.uniform(-1.0, 1.0, todo.size)
        p = 1.0 / (1.0 + k[todo] * (1.0 - m))
        ok = rng.random(todo.size) < p * p * (p + 1.0 / p - (1.0 - m * m)) / 2.0
        cos[todo[ok]] = m[ok]
        todo = todo[~ok]
    return cos


def monte_carlo(e0, crystal, n, seed=0):
    """Deposited energy (keV) of ``n`` photons of ``e0`` keV entering the crystal's face uniformly along its axis."""
    rng = np.random.default_rng(seed)
    radius, height = crystal.diameter_mm / 20.0, crystal.length_mm / 10.0
    grid = np.geomspace(5.0, 4000.0, 400)
    coeffs = np.array([response.csi_coefficients(float(e)) for e in grid])

    def mu(e):
        x = np.log(np.clip(e, 5.0, 4000.0))
        return (np.interp(x, np.log(grid), coeffs[:, 0]), np.interp(x, np.log(grid), coeffs[:, 1]))

    r, phi = radius * np.sqrt(rng.random(n)), 2 * np.pi * rng.random(n)
    pos = np.stack([r * np.cos(phi), r * np.sin(phi), np.zeros(n)], axis=1)
    d = np.tile([0.0, 0.0, 1.0], (n, 1))
    e, dep, alive = np.full(n, float(e0)), np.zeros(n), np.ones(n, bool)
    while alive.any():
        i = np.flatnonzero(alive)
        photo, compton = mu(e[i])
        step = -np.log(rng.random(i.size)) / (photo + compton)
        p, v = pos[i], d[i]
        a = v[:, 0] ** 2 + v[:, 1] ** 2
        b = 2 * (p[:, 0] * v[:, 0] + p[:, 1] * v[:, 1])
        c = p[:, 0] ** 2 + p[:, 1] ** 2 - radius**2
        with np.errstate(divide="ignore", invalid="ignore"):
            to_side = np.where(a > 1e-12, (-b + np.sqrt(np.maximum(b * b - 4 * a * c, 0.0))) / (2 * a), np.inf)
            to_face = np.where(v[:, 2] > 0, (height - p[:, 2]) / v[:, 2],
                               np.where(v[:, 2] < 0, -p[:, 2] / v[:, 2], np.inf))
        out = step >= np.minimum(to_side, to_face)
        alive[i[out]] = False
        i, step, photo, compton = i[~out], step[~out], photo[~out], compton[~out]
        pos[i] += d[i] * step[:, None]
        absorbed = rng.random(i.size) < photo / (photo + compton)
        dep[i[absorbed]] += e[i[absorbed]]
        alive[i[absorbed]] = False
        j = i[~absorbed]
        k = e[j] / MEC2_KEV
        cos = _kn_cosines(rng, k)
        e_out = e[j] / (1 + k * (1 - cos))
        dep[j] += e[j] - e_out
        e[j] = e_out
        u = d[j]
        t = np.where(np.abs(u[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
        e1 = np.cross(u, t)
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        e2 = np.cross(u, e1)
        az, sin = 2 * np.pi * rng.random(j.size), np.sqrt(1 - cos * cos)
        d[j] = u * cos[:, None] + e1 * (sin * np.cos(az))[:, None] + e2 * (sin * np.sin(az))[:, None]
    return dep


@pytest.mark.parametrize("e0", [356.0, 661.657, 1332.492])
def test_the_analytic_crystal_response_matches_an_independent_monte_carlo(e0):
    """Measured 2026-11-26 (4e5 photons): the probability of any deposit agrees to 0.3 %; the analytic
    full-energy peak is 1.5, 3.4 and 4.2 % low at 356, 662 and 1332 keV (it follows two scatters, then counts
    the photon absorbed or escaped along the mean chord), its Compton continuum below the edge 2.4, 1.3 and
    1.0 % high. So the crystal's transport is not what makes a real 1332 keV peak 16 % weaker than the
    calibrated model (docs/real-spectra.md). The bounds: 3 binomial sigmas of the Monte Carlo plus 0.5 % (total)
    and 5 % (peak, continuum) of approximation."""
    n = 400_000
    crystal = response.Crystal()
    dep = monte_carlo(e0, crystal, n)
    peaks, continuum = response.deposit_parts(e0, crystal)
    edges = response.energy_grid()
    edge = response.compton_edge_keV(e0)
    below = edges[1:] <= edge
    model = {"total": peaks[0][1] + continuum.sum(), "peak": peaks[0][1], "compton": continuum[below].sum()}
    mc = {"total": (dep > 0).mean(), "peak": (np.abs(dep - e0) < 0.01).mean(),
          "compton": ((dep > 0) & (dep < edges[1:][below][-1])).mean()}
    for key, rel in (("total", 0.005), ("peak", 0.05), ("compton", 0.05)):
        p = mc[key]
        tol = 3 * np.sqrt(p * (1 - p) / n) + rel * p
        assert abs(model[key] - p) < tol, (key, model[key], p)
