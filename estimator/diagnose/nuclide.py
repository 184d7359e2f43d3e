"""Which nuclide is the second source? (issue 30): line energies from the library, the crystal from the flight.

When ``radseek diagnose`` finds a ``second_source``, the count model gives the expected total counts per frame
of the primary (E_P), the second source (E_S) and the background (E_B). The flight's 32-channel spectra then say
which nuclide the second source is. Frames are summed into groups g (a dwell, or <= 2 s of transit: the
component mix is nearly constant inside one) and

    n_gk ~ Poisson(E_P,g p_k + E_B,g b_k + E_S,g a Q_k)

- ``p`` and ``b``, the primary's and the background's channel spectra, are FREE (31 shape parameters and a scale
  each): estimated from the flight itself, so the answer does not depend on how a template looks (a real
  RadiaCode-102 CsI(Tl) spectrum differs from any), nor on the count model's absolute strengths (the scales
  absorb them);
- ``Q`` is the hypothesis: for "same nuclide as the primary" Q = p (the flight's own primary shape, exactly);
  for another candidate nuclide, Q is predicted: its photon lines (pydecay, ICRP-107, with short-lived
  daughters) carried through a small physical response of the crystal (``Crystal``) that is FITTED ON THE
  PRIMARY'S OWN SPECTRUM p: photopeak and Klein-Nishina Compton continuum with the scattered photon's escape,
  photo/Compton attenuation of CsI from xraydb, Gaussian resolution growing as sqrt(E), backscatter and
  down-scatter from the surroundings, a gain. So the crystal's shape is learned at the primary's line(s) and
  transported to the candidate's lines; line energies and cross-sections come from the libraries.

Each hypothesis is fitted by EM (the Poisson likelihood is concave in p, b, a for a fixed Q) and scored by its
maximised log-likelihood; all candidate hypotheses have the same number of free parameters, so the log-likelihoods
compare directly (no BIC penalty needed).

Design choices, and why:
- design (a) of the issue, with Q *predicted* rather than free: a free Q compared afterwards with predictions
  loses power, and refitting the crystal per candidate (tried) lets wrong nuclides bend towards the data
  (measured Eu-152: Co-60 and K-40 come within 2x of Eu-152's own misfit), while the crystal fixed by the primary
  keeps them 7x-30x apart (measured shapes, KL divergence);
- the verdict needs the best nuclide to beat the runner-up by ``GAP_MIN`` = 5 in log-likelihood (a likelihood
  ratio e^5 ~ 150): by Royall's bound the chance that data from one simple hypothesis favour another by a
  ratio k is <= 1/k, here 0.7 %; gaps are divided by the free fit's Pearson over-dispersion (>= 1) first, a
  quasi-likelihood guard when the spectra scatter more than Poisson. Below it: ``None`` (undetermined);
- "none of the candidates": the fit with Q free is the ceiling; when it beats the best nuclide beyond noise
  (chi-square, K - 1 dof, p < 1e-3) AND by more than ``MISFIT_PER_COUNT`` = 0.04 nats per second-source count
  (the transported shapes' own error; measured in the tests' flights built from real RadiaCode-102 spectra:
  <= 0.017 for the true nuclide at 300-1300 cps, 0.023 at 5000 cps; with the true nuclide left out of the
  candidates the nearest one left 0.075-0.5 at 1300 cps and 0.038-0.2 at 300 cps), the answer is ``None``
  rather than the nearest neighbour;
- the crystal's resolution is bounded to 3-16 % FWHM at 662 keV (scintillators with photopeaks: CsI(Tl),
  NaI(Tl) 6-12 %): unbounded, a Co-60 primary (lines at 1.17 and 1.33 MeV only) traded resolution against its
  continuum and smeared the Cs-137 it then predicted (total variation 0.14 against the measured, 0.10 bounded).

Limits: the primary's shape is taken as one shape along the flight (a shape changing with distance ends in the
over-dispersion and the free-shape ceiling, making the verdict more cautious, not wrong in the tests); no gain
drift (one gain for the flight); the crystal is a 10 mm CsI cube (the RadiaCode-102) and the transport was
checked on RC-102 spectra only (Cs-137, Co-60, Ba-133, Eu-152 from one device, Am-241 from another); K-40 was
not measured as a second source here; the misfit per count of the true nuclide grows with its counts (the
transport's own error shows), so a second source far stronger than ~5000 cps at 1 m may come out "none of the
candidates" (undetermined, not wrong); between Ba-133 and Eu-152, whose low-energy parts look alike, a
moderate source of one with the other missing from the candidates can still be named as the other.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import xraydb
from scipy import optimize, stats
from scipy.special import ndtr

from radseek.dataset import Frames
from radseek.photon_lines import gamma_lines

CANDIDATES = ("Cs-137", "Co-60", "Ba-133", "Eu-152", "Am-241", "K-40")
MEC2_KEV = 510.99895  # electron rest energy (CODATA)
R_E_CM = 2.8179403262e-13  # classical electron radius (CODATA)
ELAM_MAX_KEV = 800.0  # xraydb's Elam tables are reliable up to here
CRYSTAL = "CsI"  # the RadiaCode-102's scintillator, as xraydb reads the formula
CRYSTAL_DENSITY = 4.51  # g/cm^3 (xraydb knows no CsI density)
CRYSTAL_CM = 1.0  # a 10 x 10 x 10 mm crystal
MIN_LINE_KEV = 20.0  # below this nothing reaches a 40 keV threshold, even with the resolution's tail
MIN_LINE_YIELD = 1e-3
GRID_STEP_KEV = 2.0
GRID_MAX_KEV = 3200.0
N_KN = 240  # Klein-Nishina samples per line
BACK_DEG = (110.0, 180.0)  # backscatter from the surroundings (floor, frame)
N_BACK = 8
N_DOWN = 10


# --------------------------------------------------------------------------------------------- library data


def photon_lines(nuclide: str) -> tuple[tuple[float, float], ...]:
    """(energy keV, photons per decay) of ``nuclide`` with the photons of daughters short-lived enough to be in
    equilibrium (Ba-137m under Cs-137), X-rays included (Ba-133's and Eu-152's K X-rays reach channel 0), from
    ``radseek.photon_lines`` (pydecay's ICRP-107 tables), lines below ``MIN_LINE_KEV`` left out. ValueError for a
    nuclide pydecay does not know or without photons."""
    out = tuple((e, y) for e, y in gamma_lines(nuclide, MIN_LINE_YIELD) if e >= MIN_LINE_KEV)
    if not out:
        raise ValueError(f"nuclide {nuclide!r} emits no photon above {MIN_LINE_KEV} keV in pydecay's tables")
    return out


def kn_total(e_keV: np.ndarray) -> np.ndarray:
    """Klein-Nishina total cross-section per electron (cm^2)."""
    k = np.asarray(e_keV, dtype=float) / MEC2_KEV
    l2k = np.log1p(2 * k)
    return 2 * math.pi * R_E_CM**2 * ((1 + k) / k**2 * (2 * (1 + k) / (1 + 2 * k) - l2k / k)
                                      + l2k / (2 * k) - (1 + 3 * k) / (1 + 2 * k) ** 2)


@lru_cache(maxsize=1)
def _mu_table() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """log-energy grid and CsI linear attenuation (1/cm), photoelectric and incoherent.

    xraydb (Elam et al. 2002) up to ELAM_MAX_KEV; its tables end at 1 MeV (it returns the 1 MeV values
    above, 20 % too much Compton at 1.33 MeV), so above ELAM_MAX_KEV the Compton part follows Klein-Nishina on
    the crystal's electrons (matched to Elam there) and the photoelectric part continues Elam's own power law
    of the last decade below."""
    e = np.geomspace(5.0, 5000.0, 500)
    lo = np.minimum(e, ELAM_MAX_KEV)
    with warnings.catch_warnings():  # "Elam tables are unreliable for energies > 800 keV": not used above
        warnings.simplefilter("ignore")
        ph = np.asarray(xraydb.material_mu(CRYSTAL, lo * 1e3, density=CRYSTAL_DENSITY, kind="photo"))
        inc = np.asarray(xraydb.material_mu(CRYSTAL, lo * 1e3, density=CRYSTAL_DENSITY, kind="incoh"))
        p_lo, p_hi = (float(xraydb.material_mu(CRYSTAL, x * 1e3, density=CRYSTAL_DENSITY, kind="photo"))
                      for x in (ELAM_MAX_KEV / 10 ** 0.25, ELAM_MAX_KEV))
    above = e > ELAM_MAX_KEV
    slope = math.log(p_hi / p_lo) / math.log(10 ** 0.25)
    ph[above] = p_hi * (e[above] / ELAM_MAX_KEV) ** slope
    inc[above] = inc[above] * kn_total(e[above]) / kn_total(ELAM_MAX_KEV)
    return np.log(e), np.log(ph), np.log(inc)


def mu_crystal(e_keV: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(photoelectric, Compton) linear attenuation of the crystal (1/cm) at ``e_keV`` (pair production, under
    1 % of the total below 1.5 MeV, and coherent scattering, no deposit, are left out)."""
    le, lph, linc = _mu_table()
    x = np.log(np.clip(np.asarray(e_keV, dtype=float), 5.0, 5000.0))
    return np.exp(np.interp(x, le, lph)), np.exp(np.interp(x, le, linc))


def _kn_dT(e: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Klein-Nishina d sigma / dT (unnormalised) at T = s * E for photon energies e (broadcast)."""
    k = e / MEC2_KEV
    return 2 + s**2 / (k**2 * (1 - s) ** 2) + s / (1 - s) * (s - 2 / k)


def _kn_angles(e: float, lo_deg: float, hi_deg: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Energies after Compton scattering through lo..hi deg and their Klein-Nishina weights (sum 1)."""
    th = np.radians(np.linspace(lo_deg, hi_deg, n + 1))
    mid = 0.5 * (th[1:] + th[:-1])
    k = e / MEC2_KEV
    ratio = 1.0 / (1.0 + k * (1 - np.cos(mid)))
    w = ratio**2 * (ratio + 1 / ratio - np.sin(mid) ** 2) * np.sin(mid) * np.diff(th)
    return e * ratio, w / w.sum()


# --------------------------------------------------------------------------------------------- the response


@dataclass(frozen=True)
class Crystal:
    """The few numbers that carry a line's response from one energy to another (fitted on the primary).

    fwhm_662: FWHM / E at 662 keV (FWHM grows as sqrt(E)); escape_cm: the mean path a Compton-scattered
    photon has to leave the crystal (2 V / S = 0.33 cm for a 1 cm cube); fill: the share of the twice-scattered
    photons absorbed at last (photopeak; the rest leaves T + T2 between the edge and the peak); back / down:
    shares of the photons that reach the crystal after backscatter (110-180 deg) or down-scatter (multiple,
    energies log-uniform from 40 keV up) in the surroundings; gain: recorded per deposited energy."""

    fwhm_662: float = 0.085
    escape_cm: float = 0.33
    fill: float = 0.3
    back: float = 0.08
    down: float = 0.15
    gain: float = 1.0

    def vector(self) -> np.ndarray:
        return np.array([self.fwhm_662, self.escape_cm, self.fill, self.back, self.down, self.gain])


BOUNDS = ((0.03, 0.16), (0.05, 2.0), (0.0, 1.0), (0.0, 0.6), (0.0, 0.8), (0.9, 1.1))


def _grid() -> np.ndarray:
    return np.arange(0.0, GRID_MAX_KEV + GRID_STEP_KEV, GRID_STEP_KEV)


@dataclass(frozen=True)
class _Scatter:
    """What the response of :func:`_deposits` owes to the photon energies alone (cross-sections, Klein-Nishina
    samples, grid cells): the same for every crystal a calibration tries, so computed once per set of energies."""

    ph: np.ndarray  # (n,) photoelectric and Compton attenuation at the photon energies (1/cm)
    co: np.ndarray
    mu: np.ndarray
    p_int: np.ndarray  # (n,) interaction within the crystal's length
    kn: np.ndarray  # (n, N_KN) Klein-Nishina weights of the electron energies T (each row sums to 1)
    ph1: np.ndarray  # (n, N_KN) the scattered photon's photoelectric, Compton and total attenuation
    co1: np.ndarray
    mu1: np.ndarray
    lo: np.ndarray  # (n * N_KN,) grid cell of T
    hi1: np.ndarray  # (n * N_KN,) one past the cell of the second scatter's highest deposit
    width: np.ndarray  # (n, N_KN) cells from T to that deposit


@lru_cache(maxsize=16)
def _scatter(key: bytes) -> _Scatter:
    e = np.frombuffer(key, dtype=float)
    ph, co = mu_crystal(e)
    mu = ph + co
    p_int = 1.0 - np.exp(-mu * CRYSTAL_CM)
    k = e / MEC2_KEV
    tmax = e * 2 * k / (1 + 2 * k)
    u = (np.arange(N_KN) + 0.5) / N_KN
    T = tmax[:, None] * u[None, :]
    kn = _kn_dT(e[:, None], T / e[:, None])
    kn = kn / kn.sum(1, keepdims=True)
    e1 = e[:, None] - T
    ph1, co1 = mu_crystal(e1)
    nb = len(_grid()) - 1
    lo_i = np.minimum((T / GRID_STEP_KEV).astype(int), nb - 1)
    k1 = e1 / MEC2_KEV
    top = np.minimum(T + e1 * 2 * k1 / (1 + 2 * k1), e[:, None])
    hi_i = np.minimum((top / GRID_STEP_KEV).astype(int), nb - 1)
    return _Scatter(ph, co, mu, p_int, kn, ph1, co1, ph1 + co1, lo_i.ravel(), hi_i.ravel() + 1,
                    np.maximum(hi_i - lo_i + 1, 1))


def _deposits(energies: np.ndarray, weights: np.ndarray, escape_cm: float, fill: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Deposited energy per incident photon of ``energies`` (weights): (peak energies, peak weights, continuum
    on the fine grid). The photon interacts within the crystal's length with 1 - exp(-mu L); a photo-absorption
    deposits everything; a Compton scatter gives the electron T (Klein-Nishina), and the scattered photon E' =
    E - T escapes with exp(-mu(E') escape_cm) or interacts again: photo-absorbed (all of E deposited) or
    scattered a second time, depositing T + T2 with T2 up to E''s Compton edge (spread evenly), after which
    a share ``fill`` is absorbed at last (photopeak) and the rest escapes. The energies' own part
    (:func:`_scatter`) is computed once: a calibration changes only the weights, ``escape_cm`` and ``fill``."""
    e = np.ascontiguousarray(energies, dtype=float)
    w = np.asarray(weights, dtype=float)
    sc = _scatter(e.tobytes())
    w1 = (w * sc.p_int * sc.co / sc.mu)[:, None] * sc.kn
    esc = np.exp(-sc.mu1 * escape_cm)
    nb = len(_grid()) - 1
    cont = np.bincount(sc.lo, weights=(w1 * esc).ravel(), minlength=nb)
    again = w1 * (1 - esc)
    photo2 = again * sc.ph1 / sc.mu1
    comp2 = again * sc.co1 / sc.mu1
    dens = ((1 - fill) * comp2 / sc.width).ravel()
    step = np.bincount(sc.lo, weights=dens, minlength=nb + 1) - np.bincount(sc.hi1, weights=dens, minlength=nb + 1)
    cont = cont + np.cumsum(step)[:nb]
    peak_w = w * sc.p_int * sc.ph / sc.mu + photo2.sum(1) + fill * comp2.sum(1)
    return e, peak_w, cont


def _incident(lines: tuple[tuple[float, float], ...], crystal: Crystal
              ) -> tuple[np.ndarray, np.ndarray]:
    """Photon energies reaching the crystal per decay: direct, backscattered and down-scattered."""
    e, direct, back, down = _incident_parts(lines)
    return e, (1.0 - crystal.back - crystal.down) * direct + crystal.back * back + crystal.down * down


@lru_cache(maxsize=32)
def _incident_parts(lines: tuple[tuple[float, float], ...]) -> tuple[np.ndarray, ...]:
    """The energies of :func:`_incident` and their weights per unit share of each path (direct, backscattered,
    down-scattered): the crystal only mixes the three."""
    ee, parts = [], []
    for e, y in lines:
        eb, wb = _kn_angles(e, *BACK_DEG, N_BACK)
        lo = min(40.0, e)
        ed = np.geomspace(lo, e, N_DOWN + 1)
        ee.extend([e, *eb, *np.sqrt(ed[1:] * ed[:-1])])
        zb, zd = np.zeros(N_BACK), np.zeros(N_DOWN)
        parts.append(np.array([np.r_[y, zb, zd], np.r_[0.0, y * wb, zd], np.r_[0.0, zb, np.full(N_DOWN, y / N_DOWN)]]))
    w = np.concatenate(parts, axis=1)
    return np.asarray(ee), w[0], w[1], w[2]


def channel_shape(nuclide: str, edges_keV: np.ndarray, crystal: Crystal) -> np.ndarray:
    """(K,) share of the recorded counts of ``nuclide`` in each channel [edges_k, edges_k+1) (the last open
    above), for the crystal described by ``crystal``: library lines through the response above."""
    return _shape(photon_lines(nuclide), np.asarray(edges_keV, dtype=float), crystal)[0]


def _shape(lines: tuple[tuple[float, float], ...], edges: np.ndarray, crystal: Crystal
           ) -> tuple[np.ndarray, float]:
    """(shape over channels summing to 1, recorded counts per decay)."""
    e_in, w_in = _incident(lines, crystal)
    pe, pw, cont = _deposits(e_in, w_in, crystal.escape_cm, crystal.fill)
    grid = _grid()
    centres = 0.5 * (grid[1:] + grid[:-1])
    keep = cont > 1e-12 * max(cont.max(), 1e-300)
    e = np.r_[pe, centres[keep]]
    w = np.r_[pw, cont[keep]]
    var = np.r_[np.zeros(len(pe)), np.full(int(keep.sum()), GRID_STEP_KEV**2 / 12)]
    sig = np.sqrt((crystal.fwhm_662 / (2 * math.sqrt(2 * math.log(2)))) ** 2 * 662.0 * np.maximum(e, 1.0) + var)
    m = crystal.gain * e
    s = crystal.gain * sig
    cdf = ndtr((edges[:, None] - m[None, :]) / s[None, :]) @ w
    out = np.diff(cdf)
    out[-1] = w.sum() - cdf[-2]
    out = np.maximum(out, 0.0)
    tot = out.sum()
    return out / max(tot, 1e-300), float(tot)


def calibrate(nuclide: str, shape: np.ndarray, counts: float, edges_keV: np.ndarray,
              start: Crystal | None = None) -> Crystal:
    """The ``Crystal`` whose response to ``nuclide`` best matches ``shape`` (the primary's channel shares
    measured in the flight, worth ``counts`` counts): multinomial likelihood, bounded quasi-Newton."""
    edges = np.asarray(edges_keV, dtype=float)
    lines = photon_lines(nuclide)
    p = np.clip(np.asarray(shape, dtype=float), 0.0, None)
    p = p / max(p.sum(), 1e-300)
    n = max(float(counts), 1.0)

    def nll(x: np.ndarray) -> float:
        q = _shape(lines, edges, Crystal(*x))[0]
        return -n * float((p * np.log(np.maximum(q, 1e-12))).sum())

    x0 = (start or Crystal()).vector()
    # stop at 1e-7 relative (0.01 in log-likelihood for 1e5 counts); finite differences of 1e-5 step over the
    # Klein-Nishina sampling's jitter
    res = optimize.minimize(nll, x0, method="L-BFGS-B", bounds=BOUNDS,
                            options={"maxiter": 150, "ftol": 1e-7, "eps": 1e-5})
    return Crystal(*(float(v) for v in res.x))


# --------------------------------------------------------------------------------------------- the flight fit


def group_labels(frames: Frames, chunk_s: float = 2.0) -> np.ndarray:
    """(N,) group per frame: each contiguous run of one dwell is a group, transit frames (dwell -1) are cut
    into contiguous chunks of at most ``chunk_s`` seconds. Groups only sum frames whose component mix is
    nearly the same (the frame model is linear in the per-frame expected counts, so summing is exact)."""
    n = len(frames)
    labels = np.zeros(n, dtype=int)
    if n == 0:
        return labels
    dwell = np.asarray(frames.dwell)
    t = np.asarray(frames.t, dtype=float)
    g, start_t = 0, t[0]
    for i in range(1, n):
        new = dwell[i] != dwell[i - 1] or (dwell[i] < 0 and t[i] - start_t >= chunk_s)
        if new:
            g += 1
            start_t = t[i]
        labels[i] = g
    return labels


@dataclass
class _Fit:
    ll: float
    p: np.ndarray  # (K,) primary: expected counts per unit expected_primary
    b: np.ndarray  # (K,) background, per unit expected_background
    q: np.ndarray  # (K,) second source, per unit expected_second
    mu: np.ndarray  # (G, K)


def _ll(n: np.ndarray, mu: np.ndarray, const: float) -> float:
    mu = np.maximum(mu, 1e-300)
    return float((n * np.log(mu) - mu).sum()) - const


def _fit(n: np.ndarray, E: np.ndarray, q_shape: np.ndarray | None, same: bool, const: float,
         start: _Fit | None = None, iters: int = 4000, tol: float = 1e-9) -> _Fit:
    """Poisson EM (multiplicative updates) for mu_gk = E_Pg p_k + E_Bg b_k + E_Sg q_k, all >= 0, with
    E (G, 3) = the count model's expected primary, background, second-source counts per group.

    q_shape given: q = a q_shape (one free scale a); ``same``: q = a p (the primary's own shape);
    neither: q free. p and b are always free (31 shape parameters and a scale each)."""
    Ep, Eb, Es = E[:, 0], E[:, 1], E[:, 2]
    tot = n.sum(0) + 0.5
    share = E.sum(0) / max(E.sum(), 1e-300)
    f = tot / tot.sum()
    p, b, q = (f * n.sum() * share[i] / max(E[:, i].sum(), 1e-300) for i in range(3))
    if start is not None:
        # a warm start mixed with the flat one: multiplicative updates never revive a channel that the
        # start left near zero (a 'same' fit started from the free one stuck 700 below its optimum)
        p, b, q = (0.7 * w + 0.3 * c for w, c in ((start.p, p), (start.b, b), (start.q, q)))
    a = max(float(q.sum()), 1e-12)
    if q_shape is not None:
        qs = np.asarray(q_shape, dtype=float) / max(float(np.sum(q_shape)), 1e-300)
        q = a * qs
    elif same:
        a = a / max(float(p.sum()), 1e-300)
        q = a * p
    sEp, sEb, sEs = Ep.sum(), Eb.sum(), Es.sum()
    # the three components as rows: every expected count is one product E @ P, every update's sums one Et @ R
    P = np.array([p, b, q])
    E = np.asarray(E, dtype=float)
    Et = np.ascontiguousarray(E.T)
    norm = 1.0 / np.maximum(np.array([sEp, sEb, sEs]), 1e-300)[:, None]
    prev = -np.inf
    ll = -np.inf
    for it in range(iters):
        mu = E @ P
        R = n / np.maximum(mu, 1e-300)
        if it % 20 == 0:
            ll = _ll(n, mu, const)
            if ll - prev < tol * max(abs(ll), 1.0):
                break
            prev = ll
        if same:
            # p carries both the primary and the second source (activation Ep + a Es); then the scale a
            p, b = P[0], P[1]
            act = Ep + a * Es
            p = p * (act @ R) / max(act.sum(), 1e-300)
            mu = np.outer(act, p) + np.outer(Eb, b)
            R = n / np.maximum(mu, 1e-300)
            a = a * float(Es @ R @ p) / max(sEs * p.sum(), 1e-300)
            b = b * (Eb @ R) / max(sEb, 1e-300)
            P = np.array([p, b, a * p])
            continue
        ER = Et @ R  # (3, K): each component's activation summed against the ratios
        if q_shape is None:
            P = P * ER * norm
        else:
            P[:2] = P[:2] * ER[:2] * norm[:2]
            a = a * float(ER[2] @ qs) / max(sEs, 1e-300)
            P[2] = a * qs
    mu = E @ P
    return _Fit(_ll(n, mu, const), P[0], P[1], P[2], mu)


# --------------------------------------------------------------------------------------------- the verdict

#: the log-likelihood (over-dispersion scaled) by which the best nuclide must beat the runner-up
GAP_MIN = 5.0
#: the transported shapes' own error, nats per second-source count (KL divergence); beyond it: none fits
MISFIT_PER_COUNT = 0.04


@dataclass
class NuclideChoice:
    nuclide: str | None  # e.g. "Co-60"; None when undetermined
    log_likelihood: dict[str, float]  # per candidate nuclide (incl. the primary's nuclide)
    runner_up: str | None
    gap: float  # log-likelihood of best minus runner-up
    note: str  # one line for people
    #: Pearson chi-square per degree of freedom of the free-shape fit (>= 1); gaps are judged divided by it
    dispersion: float = 1.0
    #: log-likelihood with the second source's channel shape free (the ceiling any nuclide can reach)
    log_likelihood_free: float = float("nan")
    #: share of the free shape's gain over "same as primary" that the best nuclide's shape reaches
    explained: float = float("nan")
    #: the crystal fitted on the primary's spectrum, carrying line energies to channel shapes
    crystal: Crystal | None = None
    #: expected second-source counts in the flight (the count model's, times the spectral fit's scale)
    second_counts: float = 0.0
    #: nats per second-source count by which the free shape beats the best nuclide, beyond noise
    misfit: float = 0.0


def identify_second_nuclide(frames: Frames, edges_keV: np.ndarray, primary_nuclide: str,
                            expected_primary: np.ndarray, expected_second: np.ndarray,
                            expected_background: np.ndarray,
                            candidates: tuple[str, ...] = CANDIDATES) -> NuclideChoice:
    """Which of ``candidates`` the second source is, from the flight's spectra (see the module docstring)."""
    counts = np.asarray(frames.counts, dtype=float)
    edges = np.asarray(edges_keV, dtype=float)
    N, K = counts.shape
    if len(edges) != K + 1:
        raise ValueError(f"{K} channels need {K + 1} edges, got {len(edges)}")
    E_f = np.column_stack([np.asarray(v, dtype=float).reshape(-1)
                           for v in (expected_primary, expected_background, expected_second)])
    if E_f.shape[0] != N:
        raise ValueError(f"expected counts have {E_f.shape[0]} frames, the flight {N}")
    E_f = np.clip(np.nan_to_num(E_f), 0.0, None)
    labels = group_labels(frames)
    G = int(labels.max()) + 1 if N else 0
    n = np.zeros((G, K))
    np.add.at(n, labels, counts)
    E = np.zeros((G, 3))
    np.add.at(E, labels, E_f)
    keep = E.sum(1) > 0
    n, E = n[keep], E[keep]
    names = list(dict.fromkeys((primary_nuclide, *candidates)))
    if E[:, 2].sum() <= 0 or len(n) == 0:
        return NuclideChoice(None, {}, None, 0.0, "no second-source counts expected: nothing to identify")
    const = float(np.sum([math.lgamma(v + 1) for v in n.ravel()]))
    free = _fit(n, E, None, False, const)
    same = _fit(n, E, None, True, const, start=free)
    # the crystal: fitted on the primary's own channel shares, then each candidate's lines through it
    p_counts = float(E[:, 0].sum() * free.p.sum())
    try:
        crystal = calibrate(primary_nuclide, free.p, p_counts, edges)
        uncalibrated = ""
    except ValueError:  # a primary pydecay does not know: the nominal crystal, and say so
        crystal, uncalibrated = Crystal(), f" (crystal not fitted: {primary_nuclide!r} has no library lines)"
    fits: dict[str, _Fit] = {}
    for name in names:
        if name == primary_nuclide:
            fits[name] = same
            continue
        fits[name] = _fit(n, E, channel_shape(name, edges, crystal), False, const, start=free)
    ll = {name: f.ll for name, f in fits.items()}
    # over-dispersion of the most flexible fit (Pearson): 3 free shapes of K - 1 and 3 scales
    dof = max(int((free.mu > 0).sum()) - 3 * K, 1)
    pearson = float((((n - free.mu) ** 2) / np.maximum(free.mu, 1e-9)).sum())
    disp = max(1.0, pearson / dof)
    order = sorted(ll, key=ll.get, reverse=True)
    best, runner = order[0], (order[1] if len(order) > 1 else None)
    gap = ll[best] - ll[runner] if runner else float("inf")
    gain_free = free.ll - same.ll
    explained = (ll[best] - same.ll) / gain_free if gain_free > 0 else float("nan")
    s_counts = float(E[:, 2].sum() * fits[best].q.sum())
    # none of the candidates: the free shape beats the best by more than noise (chi-square, K - 1 dof) and
    # by more than the transport's own error (MISFIT_PER_COUNT nats per second-source count)
    excess = (free.ll - ll[best]) / disp
    misfit = max(excess - (K - 1) / 2, 0.0) / max(s_counts, 1.0)
    unlisted = 2 * excess > stats.chi2.isf(1e-3, K - 1) and misfit > MISFIT_PER_COUNT
    if unlisted:
        chosen = None
        note = (f"second source's nuclide undetermined: none of {', '.join(names)} fits its spectrum (best "
                f"{best} leaves {misfit:.3f} nats per count, over {MISFIT_PER_COUNT:g}; ~{s_counts:.0f} counts)")
    elif gap / disp >= GAP_MIN:
        chosen = best
        same_as = "same as the primary" if chosen == primary_nuclide else "not the primary"
        note = (f"second source is {chosen} ({same_as}): log-likelihood {gap / disp:.1f} above {runner}, "
                f"~{s_counts:.0f} second-source counts")
    else:
        chosen = None
        note = (f"second source's nuclide undetermined: {best} leads {runner} by only {gap / disp:.1f} in "
                f"log-likelihood (needs {GAP_MIN:g}; ~{s_counts:.0f} second-source counts)")
    return NuclideChoice(chosen, ll, runner, float(gap), note + uncalibrated, disp, free.ll, float(explained),
                         crystal, s_counts, float(misfit))
