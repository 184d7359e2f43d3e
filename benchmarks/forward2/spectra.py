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

from radseek.spectrum_files import read_spectrum

REAL_SPECTRA = Path(__file__).resolve().parents[3] / "shared" / "real-spectra"
#: comparator edges of the shared datasets (keV), channel 31 is the overflow
EDGES = np.array([40.0, 83.0, 126.5, 170.5, 215.0, 260.0, 305.4, 351.4, 397.8, 444.7, 492.1, 540.0, 588.4, 637.2,
                  686.6, 736.4, 786.7, 837.5, 888.8, 940.6, 992.9, 1045.6, 1098.9, 1152.6, 1206.8, 1261.5, 1316.7,
                  1372.4, 1428.6, 1485.2, 1542.4, 1600.0, 3000.0])
CRYSTALS = ("real", "wide", "fill")


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


@lru_cache(maxsize=8)
def _measured(directory: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(lo, hi, Cs-137 net counts, background counts per the Cs live time) from the RadiaCode files."""
    cs = read_spectrum(Path(directory) / "Cs137_b.xml")
    bg = read_spectrum(Path(directory) / "bg.xml")
    e = cs.edges_keV()
    if not np.allclose(e, bg.edges_keV()):
        raise ValueError("Cs-137 and background spectra have different calibrations")
    net = cs.counts - bg.counts * cs.live_time_s / bg.live_time_s
    lo, hi, net_k = _fine(net, e)
    _, _, bg_k = _fine(bg.counts, e)
    return lo, hi, net_k, bg_k


def _smooth(mass: np.ndarray, lo: np.ndarray, hi: np.ndarray, rel_sigma_662: float) -> np.ndarray:
    """Extra Gaussian resolution, sigma(E) = rel_sigma_662 * sqrt(662 E) keV (a poorer crystal or SiPM)."""
    mid = (lo + hi) / 2
    sig = rel_sigma_662 * np.sqrt(662.0 * np.maximum(mid, 1.0))
    k = np.exp(-0.5 * ((mid[None, :] - mid[:, None]) / sig[:, None]) ** 2) / sig[:, None]
    k /= k.sum(axis=1, keepdims=True)
    return mass @ k


def source_response(crystal: str = "real", directory: str | Path = REAL_SPECTRA) -> Response:
    """The Cs-137 response of a crystal: ``real`` = the measured RadiaCode-102 spectrum (background subtracted);
    ``wide`` = the same with 4 % extra resolution at 662 keV; ``fill`` = more multiple-scatter fill between the
    Compton edge and the photopeak and a stronger backscatter bump (a larger crystal in a scattering room)."""
    lo, hi, net, _ = _measured(str(directory))
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
    return Response(lo, hi, mass / mass.sum(), f"Cs-137 ({crystal})")


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
