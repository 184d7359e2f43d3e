"""The 32-channel spectral model: where gain drift shows (total counts barely change when the gain drifts).

Counts of a frame group g in channel k, given the group's total, are multinomial with probabilities

    p_gk = w_g P_S,k(a_g) + (1 - w_g) P_B,k(a_g),        a_g = 1 + (percent_per_min / 100) * t_g / 60

- ``S`` and ``B`` are the source and background spectra of *deposited* energy, piecewise-constant densities on
  the channel bins (the first bin extended 20 % below the threshold so that a rising gain can lift pulses over
  it), estimated from the data themselves (softmax parameters, 32 each);
- the gain factor a maps deposited energy E onto the pulse height a E, so channel k collects deposited energies
  in [edges_k / a, edges_k+1 / a): ``P_T,k(a)`` is the template's mass in that interval, renormalised over the
  detected range (channel 31 is the overflow, open above);
- ``w_g`` is each group's source fraction, free per group: the spectral test then does not depend on the
  count-rate model being right (a wrong dead time or a missing wall changes w, not the spectral shapes), and the
  spectral likelihood is a separate factor from the total-count likelihood.

The gain drift is profiled: for each trial ``percent_per_min`` the templates and group amplitudes are refitted
(EM for the Poisson mixture, warm-started); the likelihood-ratio statistic 2 (nll(0) - nll(g_hat)) is chi-square
with 1 dof under no drift (scaled by the no-drift fit's deviance per dof when that exceeds 1, a quasi-likelihood
guard against misfit of the templates themselves). Pearson residuals of the no-drift fit per group and channel
are the "spectral channel over time" plot: a drifting gain leaves a dipole around the 662 keV photopeak that
grows with time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize, stats
from scipy.interpolate import PchipInterpolator

from radseek.dataset import Frames

LOW_EXTENSION = 0.2  # the first energy bin reaches this fraction below the threshold
SUB_BINS = 3  # template bins per channel: a 7 % FWHM photopeak is about one channel wide


def energy_bins(edges: np.ndarray, sub: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Template energy bins: each channel split into ``sub`` equal parts, the first reaching below threshold."""
    edges = np.asarray(edges, dtype=float).copy()
    edges[0] = edges[0] * (1 - LOW_EXTENSION)
    fine = np.concatenate([np.linspace(a, b, sub + 1)[:-1] for a, b in zip(edges[:-1], edges[1:], strict=True)]
                          + [edges[-1:]])
    return fine[:-1], fine[1:]


def response(edges: np.ndarray, gain: np.ndarray, sub: int = 1) -> np.ndarray:
    """(G, 32 channels, 32 sub energy bins): fraction of energy bin j recorded in channel k at gain a_g."""
    edges = np.asarray(edges, dtype=float)
    a = np.asarray(gain, dtype=float).reshape(-1)
    lo, hi = energy_bins(edges, sub)
    c = edges[None, :] / a[:, None]  # (G, 33) channel boundaries in deposited energy
    c_lo = c[:, :-1]
    c_hi = c[:, 1:].copy()
    c_hi[:, -1] = np.inf
    ov = np.minimum(hi[None, None, :], c_hi[:, :, None]) - np.maximum(lo[None, None, :], c_lo[:, :, None])
    return np.clip(ov, 0.0, None) / (hi - lo)[None, None, :]


def _poisson_nll(mu: np.ndarray, n: np.ndarray) -> float:
    mu = np.maximum(mu, 1e-300)
    return float((mu - n * np.log(mu)).sum())


def _em(Ms: np.ndarray, Mb: np.ndarray, n: np.ndarray, x: tuple, iters: int = 3000, tol: float = 3e-11,
        fix_s: bool = False) -> tuple[float, tuple]:
    """Poisson NMF by EM (multiplicative updates): mu_gk = A_g (Ms_g s)_k + B_g (Mb_g b)_k, all >= 0.

    With free group amplitudes this likelihood equals the multinomial one given the group totals (plus a
    constant). Returns (nll, (s, b, A, B)); s, b normalised to unit mass over energy bins.
    """
    s, b, A, B = (np.array(v, dtype=float) for v in x)
    cs = Ms.sum(1)  # (G, j): detected fraction of energy bin j
    cb = Mb.sum(1)
    prev = np.inf
    nll = np.inf
    for it in range(iters):
        us = Ms @ s
        ub = Mb @ b
        mu = A[:, None] * us + B[:, None] * ub
        R = n / np.maximum(mu, 1e-300)
        if it % 10 == 0:
            nll = _poisson_nll(mu, n)
            if prev - nll < tol * abs(nll):
                break
            prev = nll
        A_new = A * (R * us).sum(1) / np.maximum(cs @ s, 1e-300)
        B_new = B * (R * ub).sum(1) / np.maximum(cb @ b, 1e-300)
        if not fix_s:  # a calibrated detector's source template stays as it is
            s = s * np.einsum("gk,gkj->j", R * A[:, None], Ms) / np.maximum(A @ cs, 1e-300)
        b = b * np.einsum("gk,gkj->j", R * B[:, None], Mb) / np.maximum(B @ cb, 1e-300)
        A, B = A_new, B_new
        ss, sb = s.sum(), b.sum()
        s, b, A, B = s / ss, b / sb, A * ss, B * sb
    mu = A[:, None] * (Ms @ s) + B[:, None] * (Mb @ b)
    return _poisson_nll(mu, n), (s, b, A, B)


@dataclass
class SpectralFit:
    """A fit of the spectral model to frame groups (see the module docstring)."""

    percent_per_min: float
    error: float  # 1-sigma from the profile curvature (nan when not fitted)
    nll: float  # at the fitted gain drift
    nll_null: float  # at zero drift
    lr: float  # 2 (nll_null - nll)
    p_value: float  # chi-square, 1 dof
    counts: np.ndarray  # (G, 32)
    expected: np.ndarray  # (G, 32) at the fitted drift
    expected_null: np.ndarray  # (G, 32) at zero drift
    group_t: np.ndarray  # (G,)
    labels: np.ndarray  # (N,) frame -> group
    templates: np.ndarray  # (2, 32) source and background masses per energy bin (zero drift fit)
    weights: np.ndarray  # (G,) source fraction (zero drift fit)
    deviance_per_dof_null: float  # spectral deviance per dof at zero drift
    deviance_per_dof: float

    @property
    def dispersion(self) -> float:
        """Over-dispersion of the no-drift fit (>= 1). When the two-template model itself misfits (the source
        spectrum changing shape along the flight, e.g. air-scattered photons outdoors), the drift parameter
        can soak up part of that misfit; the likelihood ratio is then scaled by this factor (quasi-likelihood)."""
        return max(1.0, float(self.deviance_per_dof_null))

    @property
    def lr_scaled(self) -> float:
        return self.lr / self.dispersion

    def pearson(self, null: bool = True) -> np.ndarray:
        mu = self.expected_null if null else self.expected
        return (self.counts - mu) / np.sqrt(np.maximum(mu, 1e-9))

    @property
    def log10_p(self) -> float:
        return float(stats.chi2.logsf(max(self.lr_scaled, 0.0), 1) / np.log(10))


def group_frames(frames: Frames, n_groups: int = 40, min_s: float = 3.0) -> np.ndarray:
    """Contiguous time chunks (a sum of two-template mixtures is again one, so chunks may mix dwells)."""
    t = frames.t - frames.t[0]
    span = max(float(t[-1]), 1e-9)
    width = max(span / n_groups, min_s)
    return np.minimum((t / width).astype(int), int(span / width))


class SpectralModel:
    """Source + background spectral templates with a linear gain drift; see the module docstring."""

    def __init__(self, edges: np.ndarray, sub: int = SUB_BINS, source_template: np.ndarray | None = None):
        self.edges = np.asarray(edges, dtype=float)
        self.sub = sub
        #: (32,) source masses per energy bin from a calibrated detector file, held fixed in the fit; None = free
        self.source_template = None if source_template is None else np.asarray(source_template, dtype=float)

    @classmethod
    def from_detector_file(cls, edges: np.ndarray, detector, nuclide: str, sub: int = SUB_BINS) -> SpectralModel:
        """The source template from a calibrated detector file (``radseek.detector_file.DetectorFile``): the
        crystal's measured-energy spectrum of ``nuclide`` integrated over the template's energy bins, so only the
        background template and the group amplitudes are fitted (KeyError if the file lacks the nuclide)."""
        grid, cdf = detector.template(nuclide)
        lo, hi = energy_bins(np.asarray(edges, dtype=float), 1)
        c = np.interp(np.r_[lo, hi[-1]], grid, cdf)
        masses = np.diff(c)
        masses[-1] = cdf[-1] - c[-2]
        return cls(edges, sub, np.maximum(masses, 1e-9) / max(masses.sum(), 1e-300))

    def _prepare(self, frames: Frames, labels: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        labels = group_frames(frames) if labels is None else np.asarray(labels)
        g = int(labels.max()) + 1
        counts = np.zeros((g, frames.counts.shape[1]))
        np.add.at(counts, labels, frames.counts)
        tot = counts.sum(1)
        tw = np.bincount(labels, weights=frames.t * frames.total_counts, minlength=g)
        tmid = np.bincount(labels, weights=frames.t, minlength=g) / np.maximum(np.bincount(labels, minlength=g), 1)
        t = np.where(tot > 0, tw / np.maximum(tot, 1), tmid)
        keep = tot > 0
        remap = -np.ones(g, dtype=int)
        remap[keep] = np.arange(keep.sum())
        return counts[keep], t[keep], remap[labels]

    def _start(self, n: np.ndarray) -> tuple:
        """Background from the quietest fifth of the groups, source from the busiest fifth minus background."""
        rate = n.sum(1)
        order = np.argsort(rate)
        m = max(len(order) // 5, 1)
        qb = n[order[:m]].sum(0) + 0.5
        qb = qb / qb.sum()
        qs = np.clip((n[order[-m:]].sum(0) + 0.5) / (n[order[-m:]].sum() + 16) - 0.5 * qb, 1e-4, None)
        qs = qs / qs.sum()
        w = np.clip(1 - rate.min() / np.maximum(rate, 1e-9) * 0.9, 0.02, 0.98)
        return qs, qb, w * rate, (1 - w) * rate

    def shape(self, q: np.ndarray | None) -> np.ndarray:
        """(32 sub, 32) within-channel shape of a template: a monotone cubic (PCHIP) through its cumulative
        mass at the channel edges, so a photopeak keeps its curvature inside a channel when the gain shifts
        the edges by a fraction of a channel. ``None``: flat within each channel. No free parameters."""
        k = len(self.edges) - 1
        lo_c, hi_c = energy_bins(self.edges, 1)
        lo_f, hi_f = energy_bins(self.edges, self.sub)
        owner = np.repeat(np.arange(k), self.sub)
        if q is None:
            fine = (hi_f - lo_f) / (hi_c - lo_c)[owner]
        else:
            knots = np.r_[lo_c[0], hi_c]
            cdf = np.r_[0.0, np.cumsum(np.maximum(q, 0))]
            f = PchipInterpolator(knots, cdf)
            fine = np.maximum(np.diff(f(np.r_[lo_f[0], hi_f])), 0.0)
            tot = np.bincount(owner, weights=fine, minlength=k)
            flat = (hi_f - lo_f) / (hi_c - lo_c)[owner]
            fine = np.where(tot[owner] > 0, fine / np.where(tot[owner] > 0, tot[owner], 1.0), flat)
        S = np.zeros((len(owner), k))
        S[np.arange(len(owner)), owner] = fine
        return S

    def _responses(self, pct: float, t: np.ndarray, shapes: tuple[np.ndarray, np.ndarray]
                   ) -> tuple[np.ndarray, np.ndarray]:
        R = response(self.edges, 1.0 + pct / 100.0 * t / 60.0, self.sub)
        return R @ shapes[0], R @ shapes[1]

    def _fit_at(self, pct: float, n: np.ndarray, t: np.ndarray, x0: tuple, shapes: tuple) -> tuple[float, tuple]:
        Ms, Mb = self._responses(pct, t, shapes)
        return _em(Ms, Mb, n, x0, fix_s=self.source_template is not None)

    def expected(self, x: tuple, pct: float, t: np.ndarray, shapes: tuple) -> np.ndarray:
        s, b, A, B = x
        Ms, Mb = self._responses(pct, t, shapes)
        return A[:, None] * (Ms @ s) + B[:, None] * (Mb @ b)

    def fit(self, frames: Frames, labels: np.ndarray | None = None, drift: bool = True,
            max_shift: float = 0.15) -> SpectralFit:
        """Fit with zero drift and (if ``drift``) with the drift profiled over |shift| <= ``max_shift``.

        The profile is searched on a grid, then by Brent's method around the best grid point, each point a
        warm-started refit; the zero-drift fit is redone from the best drift solution so that an
        under-converged null cannot fake evidence.
        """
        n, t, lab = self._prepare(frames, labels)
        flat = (self.shape(None), self.shape(None))
        x_start = self._start(n)
        if self.source_template is not None:
            x_start = (self.source_template, *x_start[1:])
        _, xc = self._fit_at(0.0, n, t, x_start, flat)
        shapes = (self.shape(xc[0]), self.shape(xc[1]))
        nll0, x0 = self._fit_at(0.0, n, t, xc, shapes)
        sat = _poisson_nll(np.maximum(n, 1e-300), n)
        g_, k = n.shape
        dof = max(n.size - g_ - (2 * (k - 1) + g_ - g_), 1)  # group totals fixed; templates 2 (k - 1)
        res = dict(pct=0.0, err=float("nan"), nll=nll0, x=x0)
        if drift and t.max() > 0:
            gmax = max_shift * 100.0 * 60.0 / max(float(t.max()), 1.0)
            cache: dict[float, tuple[float, tuple]] = {0.0: (nll0, x0)}

            def prof(p: float) -> float:
                p = float(np.clip(p, -gmax, gmax))
                if p not in cache:
                    near = min(cache, key=lambda q: abs(q - p))
                    cache[p] = self._fit_at(p, n, t, cache[near][1], shapes)
                return cache[p][0]

            grid = np.linspace(-gmax, gmax, 7)
            for g in grid:
                prof(g)
            i0 = int(np.argmin([prof(g) for g in grid]))
            lo_b, hi_b = grid[max(i0 - 1, 0)], grid[min(i0 + 1, len(grid) - 1)]
            optimize.minimize_scalar(prof, bounds=(lo_b, hi_b), method="bounded",
                                     options={"xatol": (hi_b - lo_b) * 1e-3, "maxiter": 15})
            best = min(cache, key=lambda q: cache[q][0])
            f_best = cache[best][0]
            # redo the null from the best solution: the smaller null nll wins
            f0b, x0b = self._fit_at(0.0, n, t, cache[best][1], shapes)
            if f0b < nll0:
                nll0, x0 = f0b, x0b
            if f_best > nll0:
                best, f_best = 0.0, nll0
            hh = max(abs(best) * 0.2, gmax * 0.02)
            curv = (prof(best + hh) - 2 * prof(best) + prof(best - hh)) / hh**2
            err = float(1.0 / np.sqrt(curv)) if curv > 0 else float("nan")
            res = dict(pct=best, err=err, nll=f_best, x=cache[best][1] if best != 0.0 else x0)
        exp0 = self.expected(x0, 0.0, t, shapes)
        exp1 = self.expected(res["x"], res["pct"], t, shapes)
        lr = max(2 * (nll0 - res["nll"]), 0.0)
        s0, b0, A0, B0 = x0
        return SpectralFit(
            percent_per_min=float(res["pct"]), error=float(res["err"]), nll=float(res["nll"]), nll_null=nll0, lr=lr,
            p_value=float(stats.chi2.sf(lr / max(1.0, 2 * (nll0 - sat) / dof), 1)), counts=n, expected=exp1,
            expected_null=exp0, group_t=t, labels=lab,
            templates=np.vstack([s0, b0]), weights=A0 / np.maximum(A0 + B0, 1e-300),
            deviance_per_dof_null=2 * (nll0 - sat) / dof,
            deviance_per_dof=2 * (float(res["nll"]) - sat) / max(dof - 1, 1),
        )
