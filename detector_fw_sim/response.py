"""Spectral response of the CsI(Tl) crystal: what a gamma line deposits, and how that lands in channels.

Physics only, from the photon cross-sections (no drawn shapes):

- **Gamma lines** come from the ICRP-107 emission tables in ``pydecay`` (``gamma_lines``), following
  short-lived daughters in equilibrium (Cs-137 -> Ba-137m, 0.944 branching, 0.8974 photons of
  661.657 keV per Ba-137m decay: 0.847 per Cs-137 decay).
- **Attenuation coefficients** of walls and air come from NIST XCOM via ``pydecay.mu_from_material``.
  CsI is not in that table, so its cross-sections are built from physics plus the library:
  the Compton part is Klein-Nishina on CsI's electron density (Z/A = 108/259.8), the photoelectric
  part is lead's (XCOM total minus Klein-Nishina) scaled per atom by (Z/82)^n, with n fitted from
  XCOM iron and lead at 150 keV (n ~ 4.2). Coherent scattering (a few % of the total, no energy
  deposit) and pair production (< 1 % of CsI's total at 1.33 MeV) are left out. Check: the result
  is 0.0776 cm^2/g at 662 keV against XCOM's 0.0775 for CsI (tests/test_detector_response.py).
- **Deposited energy** per incident photon (``deposit_spectrum``): the photon interacts in the
  crystal with probability 1 - exp(-mu L) along the crystal length L. A photoelectric absorption
  deposits everything (photopeak). A Compton scatter gives the electron T with the Klein-Nishina
  dsigma/dT (continuum up to the Compton edge E*2k/(1+2k), k = E/mc^2, 477 keV for 662 keV); the
  scattered photon escapes with exp(-mu(E') l_esc), l_esc = 2V/S (half the mean chord of the
  cylinder), otherwise it is absorbed and the event joins the photopeak.
- **Backscatter**: a fraction ``backscatter_fraction`` of photons reaches the crystal after
  Compton scattering through angles of 110-180 deg in the surroundings (floor, frame, electronics).
  Their energies E/(1 + k(1 - cos theta)) weighted by Klein-Nishina dsigma/dOmega put the
  backscatter peak near 184 keV for Cs-137; they then deposit like any photon. The fraction is given at
  Cs-137's 662 keV; at another line energy it follows single scattering in a thick scatterer
  (``scatter_share_scale``: Klein-Nishina over the attenuation in and out of concrete, NIST XCOM via
  pydecay): against 662 keV, Co-60's lines backscatter 0.70-0.75 times as much and Ba-133's 356 keV 1.29 times
  (a thin scatterer's Klein-Nishina ratio alone: 0.60-0.66 and 1.52).
- **Resolution**: Gaussian, FWHM/E = r * sqrt(662 keV / E) (~7 % at 662 keV for CsI(Tl)).

A pulse is counted in channel k when its energy lies in [edges[k], edges[k+1]); channel 31 is the
overflow (everything above edges[31]). ``channel_fractions`` evaluates the cumulative deposited
spectrum at (possibly gain-shifted) edges, so gain drift costs one interpolation per frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from scipy.special import erf

from detector_fw_sim import electron_escape, xcom
from radseek import machine_cache

# the photon lines of a nuclide and its short-lived progeny are shared with the flight software's nuclide test
# (estimator.diagnose.nuclide): they live in the contracts package and are re-exported here for the emulator's users
from radseek.photon_lines import (  # noqa: F401
    MIN_LINE_KEV,
    MIN_LINE_YIELD,
    add_photon_lines,
    chain_photon_lines,
    gamma_lines,
)

MEC2_KEV = 510.99895  # electron rest energy
R_E_CM = 2.8179403262e-13  # classical electron radius
N_A = 6.02214076e23
CSI_DENSITY = 4.51  # g/cm^3
CSI_Z_OVER_A_MOLE = (55 + 53) / (132.905 + 126.904)  # electrons per amu
CSI_ATOMS = ((55, 132.905), (53, 126.904))  # (Z, A)
CSI_ELEMENTS = (("Cs", 132.905), ("I", 126.904))  # (symbol, A) for xraydb
PB_Z, PB_A = 82, 207.2
FE_Z, FE_A = 26, 55.845
GRID_STEP_KEV = 2.0
GRID_MAX_KEV = 4000.0


# ------------------------------------------------------------------------------------ gamma lines


def main_line_keV(nuclide: str) -> float:
    """The strongest line above 100 keV: the energy at which effective coefficients are reported."""
    lines = [(e, y) for e, y in gamma_lines(nuclide) if e >= 100.0] or list(gamma_lines(nuclide))
    return max(lines, key=lambda ey: ey[1])[0]


# ------------------------------------------------------------------------------------ cross-sections


def klein_nishina_total(E_keV: np.ndarray | float) -> np.ndarray:
    """Klein-Nishina total cross-section per electron (cm^2)."""
    k = np.asarray(E_keV, dtype=float) / MEC2_KEV
    a = (1 + k) / k**2 * (2 * (1 + k) / (1 + 2 * k) - np.log1p(2 * k) / k)
    b = np.log1p(2 * k) / (2 * k) - (1 + 3 * k) / (1 + 2 * k) ** 2
    return 2 * np.pi * R_E_CM**2 * (a + b)


def klein_nishina_dT(E_keV: float, T_keV: np.ndarray) -> np.ndarray:
    """Klein-Nishina dsigma/dT per electron (cm^2/keV) for electron kinetic energy T, zero past the edge."""
    k = E_keV / MEC2_KEV
    T = np.asarray(T_keV, dtype=float)
    s = T / E_keV
    with np.errstate(divide="ignore", invalid="ignore"):
        val = (np.pi * R_E_CM**2 / (MEC2_KEV * k**2)) * (
            2 + s**2 / (k**2 * (1 - s) ** 2) + s / (1 - s) * (s - 2 / k)
        )
    t_max = compton_edge_keV(E_keV)
    return np.where((T >= 0) & (T <= t_max), val, 0.0)


def klein_nishina_dOmega(E_keV: float, theta: np.ndarray) -> np.ndarray:
    """Klein-Nishina dsigma/dOmega per electron (cm^2/sr) for photon scattering angle theta."""
    ratio = 1.0 / (1 + E_keV / MEC2_KEV * (1 - np.cos(theta)))
    return 0.5 * R_E_CM**2 * ratio**2 * (ratio + 1 / ratio - np.sin(theta) ** 2)


def compton_edge_keV(E_keV: float) -> float:
    """Maximum electron energy of a Compton scatter: E * 2k / (1 + 2k)."""
    k = E_keV / MEC2_KEV
    return E_keV * 2 * k / (1 + 2 * k)


def scattered_energy_keV(E_keV: float | np.ndarray, theta: np.ndarray | float) -> np.ndarray:
    return np.asarray(E_keV) / (1 + np.asarray(E_keV) / MEC2_KEV * (1 - np.cos(theta)))


def _mu_rho_table(material: str, E_keV: float) -> float:
    return float(xcom.mu_over_rho(material, E_keV / 1000.0))


def _photo_per_atom_from_table(material: str, Z: int, A: float, E_keV: float) -> float:
    """Library total per atom minus Klein-Nishina on Z electrons (cm^2)."""
    total = _mu_rho_table(material, E_keV) * A / N_A
    return max(total - Z * float(klein_nishina_total(E_keV)), 1e-6 * total)


@lru_cache(maxsize=1)
def photo_z_exponent() -> float:
    """n in tau_atom ~ Z^n, from XCOM iron and lead at 150 keV (where both photo parts are well above noise)."""
    e = 150.0
    pb = _photo_per_atom_from_table("lead", PB_Z, PB_A, e)
    fe = _photo_per_atom_from_table("iron", FE_Z, FE_A, e)
    return math.log(pb / fe) / math.log(PB_Z / FE_Z)


def _csi_photo_mass(E_keV: float) -> float:
    n = photo_z_exponent()
    pb = _photo_per_atom_from_table("lead", PB_Z, PB_A, E_keV)
    per_molecule = sum(pb * (Z / PB_Z) ** n for Z, _ in CSI_ATOMS)
    return per_molecule * N_A / sum(A for _, A in CSI_ATOMS)


@lru_cache(maxsize=4096)
def csi_coefficients(E_keV: float) -> tuple[float, float]:
    """(photoelectric, Compton) linear coefficients of CsI in 1/cm at E_keV.

    Below 150 keV (where lead's 88 keV K edge spoils the scaling and CsI has its own K edges at 33.2 keV
    (I) and 36.0 keV (Cs)) the photoelectric part is the Elam photo-absorption cross-section of Cs and I
    by mass from ``xraydb`` (Elam, Ravel and Sieber, Radiat. Phys. Chem. 63 (2002) 121); the two agree
    within 1 % at 150 keV. Above the edges the old power-law continuation was right within 20 %; below
    them it was 4.5x too high (32 keV: 140 /cm against 31 /cm), which matters for X-ray lines.
    """
    compton = float(klein_nishina_total(E_keV)) * CSI_Z_OVER_A_MOLE * N_A * CSI_DENSITY
    if E_keV >= 150.0:
        photo = _csi_photo_mass(E_keV)
    else:
        mass = sum(a for _, a in CSI_ATOMS)
        photo = sum(_mu_elam_photo(el, max(E_keV, 1.0) * 1000.0) * a for (el, a) in CSI_ELEMENTS) / mass
    return photo * CSI_DENSITY, compton


def _mu_elam_photo(element: str, energy_eV: float) -> float:
    """``xraydb.mu_elam(element, energy_eV, kind="photo")`` (cm^2/g), through this machine's cache
    (``radseek.machine_cache``, keyed by xraydb's version and database file): importing xraydb (SQLAlchemy and its
    database) is 0.6 s of CPU in every process that builds a detector response, for the few dozen values a scene's
    lines and the attenuation table below 150 keV need. Each value is xraydb's, computed the first time it is asked
    for on this machine."""
    key = f"{element} {energy_eV!r}"
    values = _elam_values()
    if key not in values:
        import xraydb

        values[key] = float(xraydb.mu_elam(element, energy_eV, kind="photo"))
        path = _elam_file()
        machine_cache.write_json(path, {**_elam_read(path), **values})  # with what other processes added meanwhile
    return values[key]


def _elam_file() -> Path | None:
    db = machine_cache.package_file("xraydb", "xraydb.sqlite")  # without importing xraydb
    return machine_cache.keyed_path("xraydb-mu-elam-photo", machine_cache.package_version("xraydb"), db, ".json")


def _elam_read(path: Path | None) -> dict[str, float]:
    """The cached values at ``path``; {} when there are none, or none readable."""
    values = machine_cache.read_json(path)
    if not isinstance(values, dict) or not all(isinstance(v, float) for v in values.values()):
        return {}
    return values


@lru_cache(maxsize=1)
def _elam_values() -> dict[str, float]:
    """The cached values, read once per process (and added to as values are computed)."""
    return _elam_read(_elam_file())


def csi_mu_over_rho(E_keV: float) -> float:
    """Total (photo + Compton) mass attenuation coefficient of CsI in cm^2/g."""
    p, c = csi_coefficients(E_keV)
    return (p + c) / CSI_DENSITY


def mu_per_m(material: str, E_keV: float, density_g_cm3: float | None = None, void_fraction: float = 0.0) -> float:
    """Linear attenuation coefficient (1/m) of a library material at E_keV.

    ``density_g_cm3`` overrides the library's density (e.g. lighter concrete); ``void_fraction``
    is the hollow share of a cinder-block wall (the slab's average density is (1 - void) * density).
    """
    rho = xcom.density_g_cm3(material) if density_g_cm3 is None else density_g_cm3
    return float(xcom.mu_over_rho(material, E_keV / 1000.0)) * rho * (1.0 - void_fraction) * 100.0


# ------------------------------------------------------------------------------------ deposition


@dataclass(frozen=True)
class ResponseEffects:
    """Response effects a real crystal shows beyond the bare Klein-Nishina crystal (``radseek calibrate``).

    All default to off, which is the emulator's physics before calibration:

    - ``fwhm_exponent`` b: FWHM/E = r (662 keV / E)^b. b = 0.5 is pure photo-electron statistics; a
      SiPM-read CsI(Tl) adds a constant term (light-collection non-uniformity), so b < 0.5 (Knoll,
      *Radiation Detection and Measurement*, 4th ed., sec. 8.VI and 10.III).
    - ``k_escape``: after photo-absorption on a K shell of Cs or I, the K fluorescence photon escapes through
      the entrance face with the semi-infinite-slab probability (``k_escape_lines``); fluorescence yields,
      K-jump ratios and line energies from ``xraydb`` (Elam, Ravel and Sieber 2002 tables).
    - ``absorber_g_cm2`` of ``absorber_material`` (pydecay / NIST XCOM) between source and crystal: housing,
      source capsule and holder; it shapes the X-ray and low-energy lines.
    - ``scatter_side``: share of photons reaching the crystal after one Compton scatter through
      ``SIDE_SCATTER_DEG`` in the source holder and nearby objects (Klein-Nishina dsigma/dOmega weights);
      the existing ``backscatter_fraction`` covers 110-180 deg. Both, and ``scatter_multiple``, are shares at
      662 keV; other lines get them times ``scatter_share_scale`` (a thick scatterer).
    - ``scatter_multiple``: share of photons arriving after several scatters in the room, spread flat in
      log E from ``MULTIPLE_SCATTER_MIN_KEV`` to the line energy (the build-up continuum).
    - ``escape_scale`` multiplies the escape length of Compton-scattered photons (a crystal's shape and
      wrapping differ from the ideal cylinder).
    - ``side_scatter_min_deg``: the smallest angle of the side scatter (default ``SIDE_SCATTER_DEG[0]``, 20 deg);
      scatterers off the source-crystal line see no small angles (fitted by ``radseek calibrate``).
    - ``electron_range_factor`` f: electrons leaving the crystal near a face (``electron_escape``; mean projected
      over CSDA range, 0 = every electron stops inside), applied to every deposit, the scattered photons' too.
    """

    fwhm_exponent: float = 0.5
    k_escape: bool = False
    absorber_g_cm2: float = 0.0
    absorber_material: str = "aluminum"
    scatter_side: float = 0.0
    scatter_multiple: float = 0.0
    escape_scale: float = 1.0
    side_scatter_min_deg: float = 20.0  # = SIDE_SCATTER_DEG[0]
    electron_range_factor: float = 0.0


SIDE_SCATTER_DEG = (20.0, 110.0)
BACKSCATTER_MIN_DEG = 110.0
MULTIPLE_SCATTER_MIN_KEV = 30.0


@lru_cache(maxsize=4096)
def k_escape_lines(E_keV: float) -> tuple[tuple[float, float], ...]:
    """(deposited energy keV, probability per photo-absorbed photon) of K X-ray escape peaks at E_keV.

    The photon is absorbed at depth x below the entrance face with density mu_E exp(-mu_E x); the K X-ray
    (energy E_x, attenuation mu_x in CsI) is emitted isotropically and leaves through the face with
    probability 1/2 int_0^1 exp(-mu_x x / c) dc; integrating over x gives
    P = 1/2 [1 - (mu_x / mu_E) ln(1 + mu_E / mu_x)] (the semi-infinite slab; side faces add little
    for a 1 cm crystal at the energies where escape matters). Per element: its share of CsI's
    photo-absorption (xraydb ``mu_elam`` photo, by mass), the K-shell share (J - 1)/J from the K jump
    ratio J, the fluorescence yield omega_K and the K line intensities, all from ``xraydb``.
    Above 800 keV (where Elam's tables stop and escape is below 1e-4) nothing is returned.
    """
    import xraydb

    if E_keV > 800.0:
        return ()
    mass = sum(a for _, a in CSI_ELEMENTS)
    photo = {el: float(xraydb.mu_elam(el, E_keV * 1000.0, kind="photo")) * a / mass for el, a in CSI_ELEMENTS}
    total_photo = sum(photo.values())
    mu_e = _mu_total_interp(np.array([E_keV]))[0]
    out: dict[float, float] = {}
    for el, _ in CSI_ELEMENTS:
        edge = xraydb.xray_edge(el, "K")
        if E_keV * 1000.0 <= edge.energy:
            continue
        k_share = (edge.jump_ratio - 1.0) / edge.jump_ratio * edge.fyield * photo[el] / total_photo
        lines = xraydb.xray_lines(el, "K")
        norm = sum(line.intensity for line in lines.values())
        for line in lines.values():
            e_x = line.energy / 1000.0
            mu_x = _mu_total_interp(np.array([e_x]))[0]
            p_esc = 0.5 * (1.0 - mu_x / mu_e * math.log1p(mu_e / mu_x))
            dep = round(E_keV - e_x, 3)
            out[dep] = out.get(dep, 0.0) + k_share * line.intensity / norm * p_esc
    return tuple(sorted(out.items()))


def absorber_transmission(E_keV: np.ndarray | float, effects: ResponseEffects | None) -> np.ndarray:
    """exp(-mu/rho(E) * areal density) of the absorber between source and crystal (pydecay / NIST XCOM)."""
    E = np.atleast_1d(np.asarray(E_keV, dtype=float))
    if effects is None or effects.absorber_g_cm2 <= 0:
        return np.ones_like(E)
    mu = xcom.mu_over_rho(effects.absorber_material, np.maximum(E, 10.0) / 1000.0)
    return np.exp(-mu * effects.absorber_g_cm2)


@dataclass(frozen=True)
class Crystal:
    """A cylindrical CsI(Tl) crystal facing the source along its axis."""

    diameter_mm: float = 10.0
    length_mm: float = 10.0
    #: effects beyond the bare crystal (a calibrated detector file); None = the physics above only
    effects: ResponseEffects | None = None

    @property
    def face_area_m2(self) -> float:
        return math.pi * (self.diameter_mm / 2000.0) ** 2

    @property
    def escape_length_cm(self) -> float:
        """Half the mean chord 4V/S: the typical distance a scattered photon travels to get out."""
        r, h = self.diameter_mm / 20.0, self.length_mm / 10.0
        volume = math.pi * r * r * h
        surface = 2 * math.pi * r * r + 2 * math.pi * r * h
        scale = self.effects.escape_scale if self.effects is not None else 1.0
        return 2 * volume / surface * scale

    @property
    def mean_chord_cm(self) -> float:
        """Cauchy's mean chord 4V/S, the electrons' escape length (``electron_escape``)."""
        return electron_escape.mean_chord_cm(self.diameter_mm, self.length_mm)


def energy_grid() -> np.ndarray:
    """Bin edges of the fine deposited-energy grid (keV)."""
    return np.arange(0.0, GRID_MAX_KEV + GRID_STEP_KEV / 2, GRID_STEP_KEV)


@lru_cache(maxsize=1)
def _csi_table() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """log E, total mu (1/cm) and photoelectric share of CsI on a 60-point log grid 5 keV - 4 MeV."""
    table_e = np.geomspace(5.0, GRID_MAX_KEV, 60)
    coeffs = np.array([csi_coefficients(float(e)) for e in table_e])
    total = coeffs.sum(axis=1)
    return np.log(table_e), total, coeffs[:, 0] / total


def _mu_total_interp(energies: np.ndarray) -> np.ndarray:
    log_e, total, _ = _csi_table()
    x = np.log(np.clip(energies, 5.0, GRID_MAX_KEV))
    return np.exp(np.interp(x, log_e, np.log(total)))


def _photo_share_interp(energies: np.ndarray) -> np.ndarray:
    log_e, _, share = _csi_table()
    return np.interp(np.log(np.clip(energies, 5.0, GRID_MAX_KEV)), log_e, share)


def _kn_samples(E_keV: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Electron energies T (midpoints) and normalised Klein-Nishina weights for each photon energy in E_keV.

    Returns (len(E), n) arrays.
    """
    E = np.atleast_1d(np.asarray(E_keV, dtype=float))
    u = (np.arange(n) + 0.5) / n
    t_edge = E * 2 * (E / MEC2_KEV) / (1 + 2 * E / MEC2_KEV)
    T = t_edge[:, None] * u[None, :]
    k = E[:, None] / MEC2_KEV
    s = T / E[:, None]
    w = 2 + s**2 / (k**2 * (1 - s) ** 2) + s / (1 - s) * (s - 2 / k)
    w = w / w.sum(axis=1, keepdims=True)
    return T, w


def deposit_spectrum(E_keV: float, crystal: Crystal) -> np.ndarray:
    """Deposited energy per incident photon on the fine grid, before resolution (probabilities per bin).

    The sum is the probability that the photon deposits anything. Up to two Compton scatters are
    followed: after each, the scattered photon escapes with exp(-mu l_esc) or interacts again
    (photoelectric: full energy; a second Compton: T1 + T2 deposited, then escape or absorption).
    With ``crystal.effects.k_escape`` a share of the primary photo-absorptions deposits E - E_Kx
    (``k_escape_lines``).
    """
    peaks, out = deposit_parts(E_keV, crystal)
    out = out.copy()
    for e, p in peaks:
        out[min(max(int(e // GRID_STEP_KEV), 0), len(out) - 1)] += p
    return out


@lru_cache(maxsize=8192)
def deposit_parts(E_keV: float, crystal: Crystal) -> tuple[tuple[tuple[float, float], ...], np.ndarray]:
    """``deposit_spectrum`` as (peaks: (exact deposited energy keV, probability), continuum on the fine grid).

    Peaks are the full-energy deposit and the K X-ray escape peaks; the continuum holds every Compton deposit.
    """
    edges = energy_grid()
    photo, compton = csi_coefficients(E_keV)
    mu = photo + compton
    p_int = 1.0 - math.exp(-mu * crystal.length_mm / 10.0)
    ell = crystal.escape_length_cm
    # first Compton scatter
    T1, w1 = _kn_samples(np.array([E_keV]), 2000)
    T1, w1 = T1[0], w1[0] * p_int * compton / mu
    E1 = E_keV - T1
    mu1 = _mu_total_interp(E1)
    esc1 = np.exp(-mu1 * ell)
    again = w1 * (1 - esc1)
    photo1 = _photo_share_interp(E1)
    # second Compton scatter (coarser sampling of the first one: 200 groups of 10)
    g = (again + 1e-300).reshape(200, -1)
    w1c = again.reshape(200, -1).sum(axis=1)
    T1c = (T1.reshape(200, -1) * g).sum(axis=1) / g.sum(axis=1)
    ph1c = (photo1.reshape(200, -1) * g).sum(axis=1) / g.sum(axis=1)
    E1c = E_keV - T1c
    T2, w2 = _kn_samples(E1c, 200)
    esc2 = np.exp(-_mu_total_interp(E1c[:, None] - T2) * ell)
    w2 = w2 * (w1c * (1 - ph1c))[:, None]
    second = _histogram((T1c[:, None] + T2).ravel(), (w2 * esc2).ravel(), edges)
    primary_photo = p_int * photo / mu
    peak = primary_photo + float(np.sum(w1c * ph1c)) + float(np.sum(w2 * (1 - esc2)))
    out = _histogram(T1, w1 * esc1, edges) + second
    peaks = []
    if crystal.effects is not None and crystal.effects.k_escape:
        for e_dep, p in k_escape_lines(round(float(E_keV), 3)):
            peaks.append((e_dep, primary_photo * p))
            peak -= primary_photo * p
    out.setflags(write=False)
    return ((float(E_keV), peak), *peaks), out


#: np.histogram sorts in blocks of this many values (``BLOCK`` in numpy/lib/_histograms_impl.py)
_NP_HISTOGRAM_BLOCK = 65536


def _histogram(values: np.ndarray, weights: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """``np.histogram(values, bins=edges, weights=weights)[0]``, the same numbers bit for bit, found faster.

    For given edges numpy sorts the values (quicksort), sums the weights in that order and differences the running
    sum at the edges. The running sum depends only on the order, and values with no two equal have one order: a
    stable sort finds it in half the time on the second scatter's deposits (200 runs already sorted; the sort was
    2.1 of the 3.5 ms a 40,000-deposit call took, 273 calls in a detector's start). Anything else (equal values,
    more than one of numpy's blocks) is numpy's own call."""
    if len(values) > _NP_HISTOGRAM_BLOCK:
        return np.histogram(values, bins=edges, weights=weights)[0]
    order = np.argsort(values, kind="stable")
    ordered = values[order]
    if (ordered[1:] == ordered[:-1]).any():
        return np.histogram(values, bins=edges, weights=weights)[0]
    running = np.concatenate((np.zeros(1, dtype=weights.dtype), weights[order].cumsum()))
    at_edges = np.concatenate((ordered.searchsorted(edges[:-1], "left"), ordered.searchsorted(edges[-1:], "right")))
    total = np.zeros(edges.shape, dtype=weights.dtype)
    total += running[at_edges]
    return np.diff(total)


def scattered_energies(E_keV: float, theta_lo_deg: float, theta_hi_deg: float, n: int = 24
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Energies of photons Compton-scattered through theta_lo..theta_hi deg and their Klein-Nishina
    weights dsigma/dOmega sin(theta) dtheta (sum 1): single scattering off free electrons."""
    theta = np.linspace(math.radians(theta_lo_deg), math.radians(theta_hi_deg), n + 1)
    mid = 0.5 * (theta[1:] + theta[:-1])
    w = klein_nishina_dOmega(E_keV, mid) * np.sin(mid) * np.diff(theta)
    return scattered_energy_keV(E_keV, mid), w / w.sum()


def backscatter_energies(E_keV: float, n: int = 24, theta_min_deg: float = BACKSCATTER_MIN_DEG
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Energies of photons back-scattered through theta_min..180 deg and their Klein-Nishina weights (sum 1)."""
    return scattered_energies(E_keV, theta_min_deg, 180.0, n)


def multiple_scatter_energies(E_keV: float, n: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """The multiply-scattered continuum: n energies flat in log E from MULTIPLE_SCATTER_MIN_KEV to E (sum 1)."""
    lo = min(MULTIPLE_SCATTER_MIN_KEV, 0.9 * E_keV)
    edges = np.geomspace(lo, E_keV, n + 1)
    return np.sqrt(edges[1:] * edges[:-1]), np.full(n, 1.0 / n)


#: the surroundings' scatterers (floor, walls, bench, source holder) are thick: a line energy's scattered share
#: follows single scattering in a thick slab of this material (:func:`scatter_share_scale`)
SCATTERER_MATERIAL = "concrete"
#: the line energy (keV) at which a calibrated detector's scatter shares are given: Cs-137's 661.657 keV
SHARE_REFERENCE_KEV = 661.657


@lru_cache(maxsize=4096)
def thick_scatter_yield(E_keV: float, theta_lo_deg: float, theta_hi_deg: float, n: int = 200) -> float:
    """Photons of E_keV singly scattered through theta_lo..theta_hi deg back out of a thick slab, per electron
    and per unit areal density: integral of dsigma_KN/dOmega / (mu/rho(E) + mu/rho(E')) over the angles
    (single-scattering albedo of a semi-infinite medium, normal incidence and exit: the photon is scattered at
    the depth it reaches and must get out again at its scattered energy E'; Chandrasekhar, *Radiative
    Transfer*, 1960, sec. 9; mu/rho of ``SCATTERER_MATERIAL`` from pydecay / NIST XCOM)."""
    theta = np.linspace(math.radians(theta_lo_deg), math.radians(theta_hi_deg), n + 1)
    mid = 0.5 * (theta[1:] + theta[:-1])
    mu_in = float(xcom.mu_over_rho(SCATTERER_MATERIAL, max(E_keV, 10.0) / 1000.0))
    mu_out = xcom.mu_over_rho(SCATTERER_MATERIAL, np.maximum(scattered_energy_keV(E_keV, mid), 10.0) / 1000.0)
    return float((klein_nishina_dOmega(E_keV, mid) * np.sin(mid) * np.diff(theta) / (mu_in + mu_out)).sum())


def scatter_share_scale(E_keV: float, theta_lo_deg: float, theta_hi_deg: float) -> float:
    """A calibrated scatter share (given at :data:`SHARE_REFERENCE_KEV`) at line energy E_keV: the ratio of the
    thick-slab single-scattering yields (:func:`thick_scatter_yield`). Against Cs-137's 662 keV the Klein-Nishina
    cross-section falls with energy, but a harder photon reaches deeper and gets out more easily: Co-60's lines
    backscatter 0.70-0.75 times as much (Klein-Nishina alone 0.60-0.66) and Ba-133's 356 keV 1.29 times (alone
    1.52). The thin ratio alone moved Ba-133 away from the same device's spectrum (docs/real-spectra.md)."""
    lo, hi = round(float(theta_lo_deg), 3), round(float(theta_hi_deg), 3)
    if not (math.isfinite(lo) and math.isfinite(hi) and math.isfinite(E_keV)):
        return math.nan  # a search's trial step off the parameter space: the likelihood is nan there too
    return thick_scatter_yield(round(float(E_keV), 3), lo, hi) / thick_scatter_yield(SHARE_REFERENCE_KEV, lo, hi)


@lru_cache(maxsize=256)
def _share_scales(energies: tuple[float, ...], theta_lo_deg: float, theta_hi_deg: float) -> np.ndarray:
    """:func:`scatter_share_scale` of each line energy over one angular range (read-only)."""
    out = np.array([scatter_share_scale(e, theta_lo_deg, theta_hi_deg) for e in energies])
    out.setflags(write=False)
    return out


def scaled_shares(energies_keV: Any, backscatter_fraction: float, scatter_side: float, scatter_multiple: float,
                  side_scatter_min_deg: float = SIDE_SCATTER_DEG[0]) -> np.ndarray:
    """(3, L) back, side and multiple scatter shares of L lines: the shares given at :data:`SHARE_REFERENCE_KEV`
    times :func:`scatter_share_scale` at each line's energy. Where they would add up past 1 (far-off energies)
    they are scaled down to 1 together, so the direct share never goes negative."""
    e = tuple(float(x) for x in np.atleast_1d(energies_keV))
    theta_min = round(float(side_scatter_min_deg), 3)
    shares = np.stack([
        backscatter_fraction * _share_scales(e, BACKSCATTER_MIN_DEG, 180.0),
        scatter_side * _share_scales(e, theta_min, SIDE_SCATTER_DEG[1]),
        scatter_multiple * _share_scales(e, 0.0, 180.0)])
    return shares / np.maximum(shares.sum(0), 1.0)


def scatter_components(E_keV: float, backscatter_fraction: float, effects: ResponseEffects | None
                       ) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """(share, energies, weights) of the photons of one line reaching the crystal scattered in the surroundings;
    the unscattered share is 1 minus the sum of the shares. The shares (the emulator's default backscatter and a
    calibrated crystal's) are given at :data:`SHARE_REFERENCE_KEV` and scaled to E_keV (:func:`scaled_shares`)."""
    side = effects.scatter_side if effects is not None else 0.0
    multiple = effects.scatter_multiple if effects is not None else 0.0
    theta_min = effects.side_scatter_min_deg if effects is not None else SIDE_SCATTER_DEG[0]
    fb, fs, fm = scaled_shares(E_keV, backscatter_fraction, side, multiple, theta_min)[:, 0]
    out = []
    if backscatter_fraction > 0:
        out.append((float(fb), *backscatter_energies(E_keV)))
    if side > 0:
        out.append((float(fs), *scattered_energies(E_keV, theta_min, SIDE_SCATTER_DEG[1])))
    if multiple > 0:
        out.append((float(fm), *multiple_scatter_energies(E_keV)))
    return out


#: incident-energy nodes of the deposit matrix (continua of scattered photons are interpolated between them)
INCIDENT_NODES_KEV = np.geomspace(12.0, GRID_MAX_KEV, 160)


def incident_deposit_matrix(crystal: Crystal) -> np.ndarray:
    """(nodes, n_grid) deposited spectra of photons at ``INCIDENT_NODES_KEV`` (read-only). Photon transport only:
    the electrons' escape acts on the summed deposits (``deposited_line``), so crystals that differ only in
    ``electron_range_factor`` share one matrix."""
    eff = crystal.effects
    if eff is not None and eff.electron_range_factor:
        crystal = replace(crystal, effects=replace(eff, electron_range_factor=0.0))
    return _incident_deposit_matrix(crystal)


@lru_cache(maxsize=16)
def _incident_deposit_matrix(crystal: Crystal) -> np.ndarray:
    m = np.stack([deposit_spectrum(float(e), crystal) for e in INCIDENT_NODES_KEV])
    m.setflags(write=False)
    return m


def node_weights(energies: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Spread photons at ``energies`` onto the incident nodes, linearly in log E (keeps the total)."""
    x = np.log(np.clip(np.asarray(energies, dtype=float), INCIDENT_NODES_KEV[0], INCIDENT_NODES_KEV[-1]))
    nodes = np.log(INCIDENT_NODES_KEV)
    i = np.clip(np.searchsorted(nodes, x) - 1, 0, len(nodes) - 2)
    f = (x - nodes[i]) / (nodes[i + 1] - nodes[i])
    out = np.zeros(len(nodes))
    np.add.at(out, i, np.asarray(weights) * (1 - f))
    np.add.at(out, i + 1, np.asarray(weights) * f)
    return out


def fwhm_keV(E_keV: np.ndarray | float, fwhm_at_662: float, exponent: float = 0.5) -> np.ndarray:
    """FWHM (keV) at E: FWHM/E = r (662 / E)^b."""
    E = np.maximum(np.asarray(E_keV, dtype=float), 1.0)
    return fwhm_at_662 * 662.0 * (E / 662.0) ** (1.0 - exponent)


#: |z| beyond which 0.5 (1 + erf(z)) is exactly 0 or 1 in double precision (erfc(7) = 4e-23, far below half an ulp
#: of 1)
_ERF_SATURATED_Z = 7.0


@lru_cache(maxsize=8)
def _resolution_matrix(fwhm_at_662: float, exponent: float = 0.5) -> np.ndarray:
    """(n, n) matrix mapping deposited energy bins to measured energy bins, Gaussian FWHM/E ~ E^-exponent.

    Row i is the difference of the Gaussian's cdf 0.5 (1 + erf(z)) over the edges, z = (edge - centre_i) / (sigma_i
    sqrt 2). erf is evaluated, 64 rows at a time, only on the edges within |z| <= 7 of some row of the block: beyond,
    the cdf is exactly 0 or 1 in double precision, so the matrix is the one erf over all 2000 x 2001 edges gives,
    bit for bit, at a sixth of its CPU (0.14 s in every detector process)."""
    edges = energy_grid()
    centres = 0.5 * (edges[1:] + edges[:-1])
    sigma = fwhm_keV(centres, fwhm_at_662, exponent) / (2 * math.sqrt(2 * math.log(2)))
    sigma = np.maximum(sigma, GRID_STEP_KEV / 2)
    cdf = np.zeros((len(centres), len(edges)))
    for r0 in range(0, len(centres), 64):
        c, s = centres[r0:r0 + 64], sigma[r0:r0 + 64]
        reach = _ERF_SATURATED_Z * math.sqrt(2) * s
        lo = max(int(np.searchsorted(edges, (c - reach).min(), side="left")) - 1, 0)
        hi = min(int(np.searchsorted(edges, (c + reach).max(), side="right")) + 1, len(edges))
        z = (edges[None, lo:hi] - c[:, None]) / (s[:, None] * math.sqrt(2))
        cdf[r0:r0 + 64, lo:hi] = 0.5 * (1 + erf(z))
        cdf[r0:r0 + 64, hi:] = 1.0  # past every row's reach (below ``lo``: 0)
    return np.diff(cdf, axis=1)  # rows: deposited bin, columns: measured bin


def deposited_line(E_keV: float, crystal: Crystal, backscatter_fraction: float) -> np.ndarray:
    """Deposited energy per emitted photon of one line on the fine grid: unscattered plus scattered photons,
    each through the absorber of ``crystal.effects``, before resolution."""
    eff = crystal.effects
    comps = scatter_components(E_keV, backscatter_fraction, eff)
    direct = 1.0 - sum(c[0] for c in comps)
    dep = direct * float(absorber_transmission(E_keV, eff)[0]) * deposit_spectrum(E_keV, crystal)
    if eff is None:  # the emulator's physics before calibration: each backscattered energy exactly
        for share, energies, weights in comps:
            for e, wgt in zip(energies, weights, strict=True):
                dep = dep + share * wgt * deposit_spectrum(float(e), crystal)
        return dep
    nodes = np.zeros(len(INCIDENT_NODES_KEV))
    for share, energies, weights in comps:
        nodes += node_weights(energies, share * weights * absorber_transmission(energies, eff))
    if eff.electron_range_factor <= 0:
        return dep + nodes @ incident_deposit_matrix(crystal)
    # electrons leaving the crystal, on the line's exact peaks and on every continuum deposit, as the calibrated
    # response (spectra.model.deposited) applies them
    peaks, cont = deposit_parts(E_keV, crystal)
    a = direct * float(absorber_transmission(E_keV, eff)[0])
    pk_e = np.array([e for e, _ in peaks])
    pk_w, cont = electron_escape.apply(pk_e, a * np.array([w for _, w in peaks]),
                                       a * cont + nodes @ incident_deposit_matrix(crystal), energy_grid(),
                                       eff.electron_range_factor, crystal.mean_chord_cm)
    return cont + _binned(pk_e, pk_w)


def _binned(energies: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Peaks at exact energies as weights on the fine grid (each in the bin holding its energy)."""
    n = len(energy_grid()) - 1
    return np.bincount(np.clip((energies // GRID_STEP_KEV).astype(int), 0, n - 1), weights=weights, minlength=n)


def escaped_electrons(deposits: np.ndarray, crystal: Crystal) -> np.ndarray:
    """A deposit spectrum on the fine grid with the crystal's electron escape applied (each bin's deposits at its
    centre; unchanged without ``electron_range_factor``)."""
    eff = crystal.effects
    if eff is None or eff.electron_range_factor <= 0:
        return deposits
    return electron_escape.apply(np.zeros(0), np.zeros(0), deposits, energy_grid(), eff.electron_range_factor,
                                 crystal.mean_chord_cm)[1]


def measured_spectrum(E_keV: float, crystal: Crystal, fwhm_at_662: float, backscatter_fraction: float) -> np.ndarray:
    """Measured-energy probabilities per incident photon of one line (fine grid), resolution applied."""
    exponent = crystal.effects.fwhm_exponent if crystal.effects is not None else 0.5
    return deposited_line(E_keV, crystal, backscatter_fraction) @ _resolution_matrix(round(fwhm_at_662, 6),
                                                                                      round(exponent, 6))


def fractions_from_cdf(cdf: np.ndarray, edges_keV: np.ndarray) -> np.ndarray:
    """Per-channel probabilities from a cumulative spectrum on the grid, for edges (..., 33).

    Channel k = [edges[k], edges[k+1]) for k < 31; channel 31 = everything above edges[31].
    """
    grid = energy_grid()
    c = np.interp(edges_keV, grid, cdf)
    frac = np.diff(c, axis=-1)
    frac[..., -1] = cdf[-1] - c[..., -2]
    return frac


@dataclass(frozen=True)
class LineResponse:
    """The measured spectrum of one gamma line (fine grid) and its detection probability."""

    energy_keV: float
    photons_per_decay: float
    cdf: np.ndarray  # (n_grid + 1,) cumulative measured probability per incident photon

    def fractions(self, edges_keV: np.ndarray) -> np.ndarray:
        return fractions_from_cdf(self.cdf, edges_keV)

    def counted(self, edges_keV: np.ndarray) -> float:
        """Probability that an incident photon is counted in some channel (above edges[0])."""
        return float(self.cdf[-1] - np.interp(edges_keV[0], energy_grid(), self.cdf))


def line_response(E_keV: float, yield_: float, crystal: Crystal, fwhm_at_662: float,
                  backscatter_fraction: float) -> LineResponse:
    spec = measured_spectrum(E_keV, crystal, fwhm_at_662, backscatter_fraction)
    return LineResponse(E_keV, yield_, np.concatenate([[0.0], np.cumsum(spec)]))


@lru_cache(maxsize=32)
def nuclide_response(nuclide: str, crystal: Crystal, fwhm_at_662: float, backscatter_fraction: float
                     ) -> tuple[LineResponse, ...]:
    return tuple(line_response(e, y, crystal, fwhm_at_662, backscatter_fraction) for e, y in gamma_lines(nuclide))


def counts_per_decay(nuclide: str, crystal: Crystal, fwhm_at_662: float, backscatter_fraction: float,
                     edges_keV: np.ndarray) -> float:
    """Counts (all channels) per decay for a photon crossing the crystal face: sum of yield * P(counted)."""
    return sum(r.photons_per_decay * r.counted(edges_keV)
               for r in nuclide_response(nuclide, crystal, fwhm_at_662, backscatter_fraction))


def cps_at_1m_from_activity(activity_MBq: float, nuclide: str, crystal: Crystal, fwhm_at_662: float,
                            backscatter_fraction: float, edges_keV: np.ndarray) -> float:
    """Total recorded rate at 1 m facing the source: A * sum(yield * P_counted) * face_area / (4 pi (1 m)^2)."""
    geometric = crystal.face_area_m2 / (4 * math.pi)
    return activity_MBq * 1e6 * geometric * counts_per_decay(nuclide, crystal, fwhm_at_662, backscatter_fraction,
                                                             np.asarray(edges_keV))
