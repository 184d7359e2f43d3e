"""Detector responses for the independent forward model: measured spectra on a fine energy grid.

A response is a spectrum of *deposited* energy as counts in fine bins (``lo``, ``hi`` keV). The recorded
channel probabilities at gain a (pulse height = a * E) are the masses in [edges_k / a, edges_k+1 / a), the
last channel open above; energies below edges_0 / a are not recorded. Masses are integrated with linear
interpolation of the cumulative spectrum inside each fine bin.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from benchmarks.shared_data import shared_path
from radseek_io.spectrum_io import read_spectrum

REAL_SPECTRA = shared_path("real-spectra")
#: comparator edges of the shared datasets (keV), channel 31 is the overflow
EDGES = np.array([40.0, 83.0, 126.5, 170.5, 215.0, 260.0, 305.4, 351.4, 397.8, 444.7, 492.1, 540.0, 588.4, 637.2,
                  686.6, 736.4, 786.7, 837.5, 888.8, 940.6, 992.9, 1045.6, 1098.9, 1152.6, 1206.8, 1261.5, 1316.7,
                  1372.4, 1428.6, 1485.2, 1542.4, 1600.0, 3000.0])


@dataclass(frozen=True)
class Response:
    """A deposited-energy spectrum on fine bins (masses sum to 1)."""

    lo: np.ndarray
    hi: np.ndarray
    mass: np.ndarray
    name: str = ""

    def channel_probs(self, edges: np.ndarray, gain: np.ndarray) -> np.ndarray:
        """(G, K) probability that a pulse lands in channel k at gain a_g (rows sum to <= 1: the rest is below
        threshold)."""
        gain = np.atleast_1d(np.asarray(gain, dtype=float))
        knots = np.r_[self.lo[0], self.hi]
        cum = np.r_[0.0, np.cumsum(self.mass)]
        c = np.interp(edges[None, :] / gain[:, None], knots, cum)  # (G, K+1)
        p = np.diff(c, axis=1)
        p[:, -1] = cum[-1] - c[:, -2]  # overflow: everything above the last comparator
        return np.clip(p, 0.0, None)


def _fine(counts: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    keep = (edges[:-1] >= 0.0) & (np.diff(edges) > 0)
    return edges[:-1][keep], edges[1:][keep], np.clip(counts[keep], 0.0, None)


#: the measured file of each nuclide in ``shared/real-spectra`` (same device, day and calibration as bg.xml)
MEASURED = {"Cs-137": "Cs137_b.xml", "Co-60": "Co60_a.xml", "Eu-152": "Eu152_b.xml", "Ba-133": "Ba133_a.xml"}
NUCLIDES = tuple(MEASURED)
#: analytic crystals: FWHM/E at 662 keV (FWHM grows as sqrt(E)), peak-to-total at 662 keV and its power law in
#: energy (P/T(E) = pt * (662 / E)^k, at most 1), backscatter bump and multiple-scatter fill (shares of the
#: Compton part), crystal thickness for the interaction probability (cm)
ANALYTIC = {
    "analytic-a": {"fwhm": 0.065, "pt": 0.32, "k": 1.6, "backscatter": 0.03, "fill": 0.0, "cm": 1.0},
    "analytic-b": {"fwhm": 0.115, "pt": 0.16, "k": 1.1, "backscatter": 0.12, "fill": 0.12, "cm": 2.5},
}
CRYSTALS = ("real", "wide", "fill", *ANALYTIC)
MEC2_KEV = 510.99895


@lru_cache(maxsize=16)
def _measured(directory: str, nuclide: str = "Cs-137") -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(lo, hi, net counts of ``nuclide``, background counts per that file's live time) from the RadiaCode
    files: the room background scaled by live time is subtracted."""
    if nuclide not in MEASURED:
        raise ValueError(f"no measured spectrum of {nuclide!r}; have {NUCLIDES}")
    src = read_spectrum(Path(directory) / MEASURED[nuclide])
    bg = read_spectrum(Path(directory) / "bg.xml")
    e = src.edges_keV()
    if not np.allclose(e, bg.edges_keV()):
        raise ValueError(f"{nuclide} and background spectra have different calibrations")
    net = src.counts - bg.counts * src.livetime / bg.livetime
    lo, hi, net_k = _fine(net, e)
    _, _, bg_k = _fine(bg.counts * src.livetime / bg.livetime, e)
    return lo, hi, net_k, bg_k


def _smooth(mass: np.ndarray, lo: np.ndarray, hi: np.ndarray, rel_sigma_662: float) -> np.ndarray:
    """Extra Gaussian resolution, sigma(E) = rel_sigma_662 * sqrt(662 E) keV (a poorer crystal or SiPM)."""
    mid = (lo + hi) / 2
    sig = rel_sigma_662 * np.sqrt(662.0 * np.maximum(mid, 1.0))
    k = np.exp(-0.5 * ((mid[None, :] - mid[:, None]) / sig[:, None]) ** 2) / sig[:, None]
    k /= k.sum(axis=1, keepdims=True)
    return mass @ k


@lru_cache(maxsize=8)
def photon_lines(nuclide: str, min_kev: float = 30.0, min_yield: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """(energies keV, photons per decay) of ``nuclide`` from pydecay's ICRP-107 emissions, with its short-lived
    (< 1 day) radioactive daughters weighted by pydecay's branching (Cs-137 -> Ba-137m: 0.944 x 0.897 at
    661.657 keV); lines below ``min_kev`` or ``min_yield`` are dropped."""
    import pydecay
    from pydecay.nuclide import Nuclide

    lines: dict[float, float] = {}
    todo = [(nuclide, 1.0)]
    while todo:
        name, w = todo.pop()
        try:
            rows = pydecay.emissions(name)
        except Exception:  # pydecay's own NuclideNotFoundError / DataFormatError: no photons listed
            rows = []
        for r in rows:
            if r.get("is_photon") and r["E_MeV"] * 1e3 >= min_kev:
                e = round(r["E_MeV"] * 1e3, 3)
                lines[e] = lines.get(e, 0.0) + w * float(r["prob"])
        nuc = Nuclide.load(name)
        if nuc.is_stable:
            continue
        for d, b in zip(nuc.progeny, nuc.branching, strict=False):
            dn = Nuclide.load(d)
            if not dn.is_stable and dn.half_life_s < 86400.0:
                todo.append((d, w * float(b)))
    e = np.array(sorted(k for k, v in lines.items() if v >= min_yield))
    if not len(e):
        raise ValueError(f"pydecay has no photon lines of {nuclide!r}")
    return e, np.array([lines[k] for k in e])


def _csi_interaction(e_kev: np.ndarray, cm: float) -> np.ndarray:
    """Probability that a photon of energy E interacts in ``cm`` of CsI (xraydb total attenuation, 4.51 g/cm3)."""
    import warnings

    import xraydb

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Elam's tables are rougher above 800 keV; ample for a shape
        mu = np.array([xraydb.material_mu("CsI", float(e) * 1e3, density=4.51) for e in e_kev])
    return 1.0 - np.exp(-mu * cm)


def _klein_nishina_T(e: float, t: np.ndarray) -> np.ndarray:
    """Klein-Nishina d(sigma)/dT (unnormalised) of a photon of energy e giving kinetic energy t to an electron."""
    eps = e / MEC2_KEV
    s = np.clip(t / e, 0.0, 1.0 - 1e-9)
    return 2.0 + s**2 / (eps**2 * (1 - s) ** 2) + s / (1 - s) * (s - 2.0 / eps)


@lru_cache(maxsize=16)
def analytic_response(crystal: str, nuclide: str = "Cs-137") -> Response:
    """An analytic crystal response, built from the nuclide's photon lines (pydecay) and not from any measured
    spectrum: per line E a Gaussian photopeak (FWHM = fwhm * 662 * sqrt(E / 662) keV) holding the share
    P/T(E) of the interacting photons, a Klein-Nishina Compton continuum up to the edge
    2E^2 / (mc^2 + 2E), a backscatter bump at E / (1 + 2E / mc^2) and a flat multiple-scatter fill between
    edge and peak; lines weighted by photons per decay x interaction probability in the crystal (xraydb)."""
    p = ANALYTIC[crystal]
    e_lines, y = photon_lines(nuclide)
    w = y * _csi_interaction(e_lines, p["cm"])
    lo = np.arange(0.0, 3000.0, 3.0)
    hi, mid = lo + 3.0, lo + 1.5
    mass = np.zeros_like(mid)
    for e, wi in zip(e_lines, w, strict=True):
        pt = min(1.0, p["pt"] * (662.0 / e) ** p["k"])
        edge = 2 * e**2 / (MEC2_KEV + 2 * e)
        comp = np.where(mid < edge, _klein_nishina_T(e, mid), 0.0)
        bs_e = e / (1 + 2 * e / MEC2_KEV)
        bs = np.exp(-0.5 * ((mid - bs_e) / (0.15 * bs_e)) ** 2)
        fill = ((mid >= edge) & (mid < e)).astype(float)
        parts = [(comp, 1.0 - p["backscatter"] - p["fill"]), (bs, p["backscatter"]), (fill, p["fill"])]
        cont = sum(f * x / x.sum() for x, f in parts if x.sum() > 0)
        peak = np.zeros_like(mid)
        peak[int(np.clip(np.searchsorted(hi, e), 0, len(mid) - 1))] = 1.0
        mass += wi * (pt * peak + (1 - pt) * cont / cont.sum())
    mass = _smooth(mass, lo, hi, p["fwhm"] / 2.3548)
    return Response(lo, hi, mass / mass.sum(), f"{nuclide} ({crystal})")


def source_response(crystal: str = "real", directory: str | Path = REAL_SPECTRA, nuclide: str = "Cs-137"
                    ) -> Response:
    """The response of a crystal to ``nuclide``: ``real`` = the measured RadiaCode-102 spectrum (background
    subtracted by live time; Cs-137, Co-60, Eu-152, Ba-133); ``wide`` = the same with 4 % extra resolution at
    662 keV; ``fill`` (Cs-137 only) = more multiple-scatter fill between the Compton edge and the photopeak and
    a stronger backscatter bump (a larger crystal in a scattering room); ``analytic-a`` / ``analytic-b`` =
    :func:`analytic_response` (any nuclide pydecay has lines for)."""
    if crystal in ANALYTIC:
        return analytic_response(crystal, nuclide)
    if crystal == "fill" and nuclide != "Cs-137":
        raise ValueError(f"crystal 'fill' is Cs-137 only, got {nuclide!r}")
    lo, hi, net, _ = _measured(str(directory), nuclide)
    mass = net / net.sum()
    mid = (lo + hi) / 2
    if crystal == "wide":
        mass = _smooth(mass, lo, hi, 0.04)
    elif crystal == "fill":
        width = hi - lo
        fill = np.where((mid > 480) & (mid < 620), 1.0, 0.0) * width
        bump = np.exp(-0.5 * ((mid - 195.0) / 25.0) ** 2) * width
        mass = mass + 0.10 * fill / fill.sum() + 0.06 * bump / bump.sum()
    elif crystal != "real":
        raise ValueError(f"crystal must be one of {CRYSTALS}, got {crystal!r}")
    return Response(lo, hi, mass / mass.sum(), f"{nuclide} ({crystal})")


def scatter_response() -> Response:
    """Photons scattered once or more on their way (floor, air, walls) before reaching the crystal: a continuum
    falling with energy, a backscatter bump near 200 keV, nothing in the photopeak."""
    lo = np.arange(0.0, 3000.0, 5.0)
    hi = lo + 5.0
    mid = (lo + hi) / 2
    dens = np.where((mid > 30) & (mid < 640), np.exp(-mid / 220.0) * (1 + 0.5 * (mid > 150) * (mid < 260)), 0.0)
    return Response(lo, hi, dens / dens.sum(), "scattered Cs-137")


def background_response(directory: str | Path = REAL_SPECTRA) -> Response:
    """The measured room background of the same device (1800 s)."""
    lo, hi, _, bg = _measured(str(directory))
    return Response(lo, hi, bg / bg.sum(), "room background")


def total_variation(a: Response, b: Response, edges: np.ndarray = EDGES) -> float:
    """Total-variation distance of two responses over the comparator channels at unit gain."""
    pa, pb = a.channel_probs(edges, np.ones(1))[0], b.channel_probs(edges, np.ones(1))[0]
    return 0.5 * float(np.abs(pa / pa.sum() - pb / pb.sum()).sum())
