"""The 32-channel spectral model: where gain drift shows (total counts barely change when the gain drifts).

Counts of a frame group g in channel k are Poisson with means

    mu_gk = A_g P_S,k(a_g) + B_g P_B,k(a_g),        a_g = 1 + (percent_per_min / 100) * (t_g - t_ref) / 60

- ``S`` and ``B`` are the source and background spectra of *deposited* energy, 32 masses on the channel bins
  (the first bin extended 20 % below the threshold so that a rising gain can lift pulses over it), estimated
  from the flight's own spectra: with ``t_ref`` the count-weighted mean time they are the flight's mean source
  and background spectra, and the drift is each group's spectrum stretched against them. No template shape is
  assumed (any crystal, Cs-137 or Co-60 alike);
- the gain factor a maps deposited energy E onto the pulse height a E, so channel k collects deposited energies
  in [edges_k / a, edges_k+1 / a); ``P_T,k(a)`` integrates the template's density over that interval, the
  density inside a channel being a smooth curve with the channel masses (exp of a cubic spline through the log
  densities: a photopeak one channel wide keeps its flanks, where the drift signal is);
- ``A_g`` (the source amplitude) is free per group: the spectral test does not depend on the count-rate model
  being right (a wrong dead time or a missing wall changes A, not the spectral shapes). The background rate is
  steady, ``B_g = duration_g exp(b0 + b1 t~_g)``: free per group, the background amplitude would let the second
  template become "the source, shifted" and follow a drift (to first order a drifting spectrum is the mean
  spectrum plus its gain derivative growing with time) -- the reason a 0.9 %/min drift went unnamed on crystals
  whose background is a small part of the counts (issue 30).

All parameters (log masses, amplitudes, the drift) are fitted by damped Fisher scoring; the likelihood-ratio
statistic 2 (nll(0) - nll(drift)) is chi-square with 1 dof under no drift, divided by the drifting fit's Pearson
chi-square per dof when that exceeds 1 (quasi-likelihood: misfit the model has no term for, such as a spectrum
changing shape with distance beyond what the free source amplitudes absorb). A shape nuisance, a scattered
continuum (free masses) growing with the distance proxy (source rate)^-1/2, joins when the no-drift fit misfits
by more than 3 sd (outdoor buildup): always in, it would take part of a real drift whenever the distance changes
steadily along the flight.

Pearson residuals of the no-drift fit per group and channel are the "spectral channel over time" plot: a
drifting gain leaves a dipole around the photopeak that grows with time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats
from scipy.interpolate import PchipInterpolator

from radseek.dataset import Frames

LOW_EXTENSION = 0.2  # the first energy bin reaches this fraction below the threshold
FIRST_CHANNEL = 0
GAMMA_STEP = 0.01  # %/min: the grid on which the stretched responses are integrated exactly
C_FLOOR = 1e-12  # the scattered-continuum template's masses stay above this (log parameters)
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
    constant). Returns (nll, (s, b, A, B)); s, b normalised to unit mass over energy bins. The scoring fit's
    start (free background amplitudes, flat within-channel shapes, no drift).
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
    nuisance: np.ndarray | None = None  # (32,) the scattered-continuum masses (None when not fitted)
    pearson_per_dof: float = float("nan")  # Pearson chi-square per dof of the drifting fit

    @property
    def dispersion(self) -> float:
        """Over-dispersion of the spectral fit (>= 1): the Pearson chi-square per dof of the drifting fit (the
        no-drift deviance when that is not known). The likelihood ratio is divided by it (quasi-likelihood), a
        guard against misfit the model has no term for; misfit the drift explains does not count against it."""
        v = self.pearson_per_dof if np.isfinite(self.pearson_per_dof) else self.deviance_per_dof_null
        return max(1.0, float(v))

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


def _alternate(fitter: _Scorer, z: np.ndarray | None, nll0: float, p0: dict, res: dict, rounds: int = 4
               ) -> tuple[float, dict, dict]:
    """The null again from the drifting solution and the drift from the null, until neither improves: the
    template fit has flat directions along which scoring crawls, and a better null optimum found from elsewhere
    must not count as evidence, nor a better drifting one be missed. The drifting fit is never worse than the
    null (nested)."""
    for _ in range(rounds):
        nll0b, p0b = fitter.fit(dict(res["p"], gamma=0.0), z, gamma_free=False)
        nll1, p1 = fitter.fit(dict(p0b, gamma=res["p"]["gamma"]), z, gamma_free=True)
        better = max(nll0 - nll0b, res["nll"] - nll1)
        if nll0b < nll0:
            nll0, p0 = nll0b, p0b
        if nll1 < res["nll"]:
            res = dict(nll=nll1, p=p1)
        if better < 0.05:
            break
    if nll0 < res["nll"]:
        res = dict(nll=nll0, p=p0)
    return nll0, p0, res


class SpectralModel:
    """Source + background spectral templates with a linear gain drift; see the module docstring."""

    def __init__(self, edges: np.ndarray, sub: int = SUB_BINS, source_template: np.ndarray | None = None,
                 nuisance: bool | str = "auto", first_channel: int = FIRST_CHANNEL):
        self.edges = np.asarray(edges, dtype=float)
        self.sub = sub
        #: a scattered continuum (free masses) added to the source in proportion to the distance proxy
        #: (source rate)^-1/2: True, False or "auto" (when the no-drift fit misfits by > 3 sd; with the distance
        #: changing steadily along a flight it takes part of a real drift, so it stays out when not needed)
        self.nuisance = nuisance
        #: channels below this are left out of the spectral likelihood (the threshold channel: its drift signal is
        #: the density just below the threshold, which the channel counts never show)
        self.first_channel = first_channel
        #: (32,) source masses per energy bin from a calibrated detector file, held fixed in the fit; None = free
        self.source_template = None if source_template is None else np.asarray(source_template, dtype=float)

    @classmethod
    def from_detector_file(cls, edges: np.ndarray, detector, nuclide: str, sub: int = SUB_BINS) -> SpectralModel:
        """The source template from a calibrated detector file (``radseek_io.detector_file.DetectorFile``): the
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

    def _fit_at(self, pct: float, n: np.ndarray, t: np.ndarray, x0: tuple, shapes: tuple,
                iters: int = 3000) -> tuple[float, tuple]:
        R = response(self.edges, 1.0 + pct / 100.0 * t / 60.0, self.sub)
        Ms, Mb = (R @ sh for sh in shapes)
        return _em(Ms, Mb, n, x0, iters=iters, fix_s=self.source_template is not None)

    def fit(self, frames: Frames, labels: np.ndarray | None = None, drift: bool = True,
            max_shift: float = 0.15, second: tuple[np.ndarray, np.ndarray] | None = None) -> SpectralFit:
        """See ``_fit``; run with one BLAS thread (its matrices are ~200 x 200: a thread pool only adds
        synchronisation, ten times slower on a loaded machine)."""
        from estimator.diagnose.threads import blas_threads

        with blas_threads(1):
            return self._fit(frames, labels, drift, max_shift, second)

    def _fit(self, frames: Frames, labels: np.ndarray | None = None, drift: bool = True,
             max_shift: float = 0.15, second: tuple[np.ndarray, np.ndarray] | None = None) -> SpectralFit:
        """Fit with zero drift and (if ``drift``) with the drift free, |shift| <= ``max_shift`` over the flight.

        ``second``: per frame, the count model's expected counts of the primary source and of a second source.
        The second source's spectrum (free masses, its own nuclide's whatever it is) then joins the model in
        place of the shape nuisance, with each group's amount in the ratio the count model gives: a second
        nuclide whose share changes along the flight changes the spectrum's shape over time, which one source
        template cannot follow (the verdict called every Co-60 second source unexplained for it).

        Every fit is damped Fisher scoring on all parameters at once (template log masses, source amplitudes,
        background rate, the optional shape nuisance and the drift itself); the drifting fit starts from the
        no-drift one and from two drifts either side, null and drift are refitted from each other until neither
        improves, then the within-channel shapes are re-estimated from the drifting fit's templates.
        """
        n_all, t, lab = self._prepare(frames, labels)
        g_, k = n_all.shape
        used = np.ones(k, dtype=bool)
        used[: self.first_channel] = False
        n = n_all[:, used]
        x_start = self._start(n_all)
        fix_s = self.source_template is not None
        if fix_s:
            x_start = (self.source_template, *x_start[1:])
        flat = (self.shape(None),) * 2
        _, xc = self._fit_at(0.0, n_all, t, x_start, flat, iters=300)
        tau = self._durations(frames, lab, g_)
        # the gain is 1 at the count-weighted mean time: the templates are then the flight's mean spectrum,
        # whose within-channel shapes the start (a fit to all groups) estimates
        t_ref = float(np.average(t, weights=np.maximum(n.sum(1), 1e-9)))
        fitter = _Scorer(self.edges, t - t_ref, n, used, (xc[0], xc[1]), fix_s, tau)
        # EM leaves exact zeros (a zero mass never moves again under log steps, and a drift moving mass into a
        # cell the model holds empty would freeze the drift): floor the masses
        qs, qb = (np.maximum(q, 1e-7 * q.max()) for q in xc[:2])
        if fix_s:  # held as given
            qs = self.source_template / self.source_template.sum()
        bb = np.array([np.log(max(float(xc[3].sum() * qb.sum()), 1e-300) / tau.sum()), 0.0])
        p0 = dict(qs=qs / qs.sum(), qb=qb / qb.sum(), a_s=np.maximum(xc[2], 1e-6 * xc[2].max()) * qs.sum(),
                  bb=bb, a_b=fitter.background(bb), c=None, gamma=0.0)
        nll0, p0 = fitter.fit(p0, None, gamma_free=False)
        z = None
        if second is not None:
            z = self._share(second, lab, g_)
        elif self.nuisance == "auto":
            # the scattered continuum joins only when the no-drift fit misfits by more than 3 sd of its Pearson
            # chi-square per dof: it can also take part of a drift, and without misfit it is not needed
            mu = fitter.mu(p0, None)
            big = mu >= 2.0
            dof_big = max(big.sum() - (g_ + 2 * used.sum()) * big.mean(), 1.0)
            disp0 = float(((n - mu)[big] ** 2 / mu[big]).sum() / dof_big)
            if disp0 > 1 + 3 * np.sqrt(2 / dof_big):
                z = self._distance(p0["a_s"], frames, lab, g_)
        elif self.nuisance:
            z = self._distance(p0["a_s"], frames, lab, g_)
        if z is not None:
            nll0, p0 = fitter.fit(dict(p0, c=np.full(k, 1e-3 / k)), z, gamma_free=False)
        res = dict(nll=nll0, p=p0)
        err = float("nan")
        if drift and t.max() > t.min():
            gmax = max_shift * 100.0 * 60.0 / max(float(t.max() - t.min()), 1.0)
            fitter.gmax = gmax
            for g0 in (0.0, gmax / 4, -gmax / 4):
                nll1, p1 = fitter.fit(dict(p0, gamma=g0), z, gamma_free=True)
                if nll1 < res["nll"]:
                    res = dict(nll=nll1, p=p1)
            nll0, p0, res = _alternate(fitter, z, nll0, p0, res)
            # the within-channel shapes again from the drifting fit's templates (the start's are those of a
            # spectrum smeared by the drift), and both fits redone with them
            fitter = _Scorer(self.edges, t - t_ref, n, used, (res["p"]["qs"], res["p"]["qb"]), fix_s, tau)
            fitter.gmax = gmax
            nll0, p0 = fitter.fit(p0, z, gamma_free=False)
            nll1, p1 = fitter.fit(res["p"], z, gamma_free=True)
            nll0, p0, res = _alternate(fitter, z, nll0, p0, dict(nll=nll1, p=p1))
            var = fitter.variance(res["p"], z)
            err = float(np.sqrt(var)) if var > 0 else float("nan")
        p1 = res["p"]
        # cells, minus group amplitudes, template masses (mass sums fixed), the nuisance, and the drift
        n_par = g_ + 2 + (1 if fix_s else 2) * (used.sum() - 1) + (used.sum() if z is not None else 0)
        dof = max(n.size - n_par, 1)
        sat = _poisson_nll(np.maximum(n, 1e-300), n)
        mu1 = fitter.mu(p1, z)
        # Pearson chi-square per dof over the cells expecting >= 2 counts (a cell expecting 0.01 that holds one
        # count adds 100: a few such cells would scale a real drift away), dof in proportion
        big = mu1 >= 2.0
        pearson = float(((n - mu1)[big] ** 2 / mu1[big]).sum() / max((dof - 1) * big.mean(), 1.0))
        lr = max(2 * (nll0 - res["nll"]), 0.0)
        disp = max(1.0, pearson)
        return SpectralFit(
            percent_per_min=float(p1["gamma"]), error=err * np.sqrt(disp), nll=float(res["nll"]), nll_null=nll0,
            lr=lr, p_value=float(stats.chi2.sf(lr / disp, 1)), counts=n_all,
            expected=fitter.mu(p1, z, full=True), expected_null=fitter.mu(p0, z, full=True), group_t=t, labels=lab,
            templates=np.vstack([p0["qs"], p0["qb"]]), weights=p0["a_s"] / np.maximum(p0["a_s"] + p0["a_b"], 1e-300),
            deviance_per_dof_null=2 * (nll0 - sat) / dof,
            deviance_per_dof=2 * (float(res["nll"]) - sat) / max(dof - 1, 1),
            nuisance=p0["c"], pearson_per_dof=pearson,
        )

    @staticmethod
    def _share(second: tuple[np.ndarray, np.ndarray], lab: np.ndarray, g_: int) -> np.ndarray:
        """(G,) the second source's expected counts per group over the primary's (the covariate of its
        component: its amplitude is the primary's times this ratio times its masses' sum)."""
        first, other = (np.asarray(a, dtype=float) for a in second)
        ok = lab >= 0
        s1 = np.bincount(lab[ok], weights=first[ok], minlength=g_)[:g_]
        s2 = np.bincount(lab[ok], weights=other[ok], minlength=g_)[:g_]
        r = s2 / np.maximum(s1, 1e-9 * max(float(s1.max()), 1e-300))
        return r / max(float(r.max()), 1e-300)

    @staticmethod
    def _durations(frames: Frames, lab: np.ndarray, g_: int) -> np.ndarray:
        """(G,) live durations of the groups (frames counted as one unit each when durations are unknown)."""
        dur = getattr(frames, "duration", None)
        dur = np.ones(len(lab)) if dur is None else np.asarray(dur, dtype=float)
        ok = lab >= 0
        return np.maximum(np.bincount(lab[ok], weights=dur[ok], minlength=g_)[:g_], 1e-9)

    def _distance(self, a_s: np.ndarray, frames: Frames, lab: np.ndarray, g_: int) -> np.ndarray | None:
        """(G,) the covariate of the shape nuisance: the distance proxy d = (source rate)^-1/2 (proportional to
        the distance for an inverse-square source) minus its smallest value, in units of its sd (weights:
        source counts); None when the distance hardly varies (the nuisance would only duplicate the source
        template)."""
        tau = self._durations(frames, lab, g_)
        rate = a_s / np.maximum(tau, 1e-9)
        rate = np.maximum(rate, 1e-3 * max(float(rate.max()), 1e-300))
        d = rate ** -0.5
        w = a_s / max(float(a_s.sum()), 1e-300)

        m = float(w @ d)
        sd = float(np.sqrt(w @ (d - m) ** 2))
        if g_ < 4 or sd < 0.02 * m:
            return None
        return np.minimum((d - d.min()) / sd, 8.0)


def histospline_cdf(lo: np.ndarray, hi: np.ndarray, q: np.ndarray, fine: int = 48, iters: int = 60):
    """A smooth density with the bins' masses ``q`` exactly: exp of a natural cubic spline through the log
    densities at the bin centres (so a Gaussian photopeak, a parabola in log density, keeps its curvature
    inside a channel and its density at the channel edges), the knot values found by a fixed-point iteration
    on the bin masses. Returns the cumulative mass as a function of energy (linear between ``fine`` points per
    bin). A monotone cubic through the cumulative masses (PCHIP) instead puts the density at an edge near the
    harmonic mean of the two bins: half the true value at the flank of a photopeak one channel wide."""
    from scipy.interpolate import CubicSpline

    q = np.maximum(np.asarray(q, dtype=float), 1e-12 * max(float(np.max(q)), 1e-300))
    w = hi - lo
    x = np.concatenate([np.linspace(a, b, fine + 1)[:-1] for a, b in zip(lo, hi, strict=True)] + [hi[-1:]])
    owner = np.minimum(np.searchsorted(hi, x, side="right"), len(q) - 1)
    centre = (lo + hi) / 2
    phi = np.log(q / w)
    phi = np.maximum(phi, phi.max() - 12.0)
    for _ in range(iters):
        dens = np.exp(np.clip(CubicSpline(centre, phi, bc_type="natural")(x), -700, 700))
        seg = 0.5 * (dens[1:] + dens[:-1]) * np.diff(x)
        m = np.bincount(owner[:-1], weights=seg, minlength=len(q))
        ratio = q / np.maximum(m, 1e-300)
        phi = phi + np.log(ratio)
        phi = np.maximum(phi, phi.max() - 12.0)  # a near-empty bin must not make the spline ring
        if np.max(np.abs(np.log(ratio))) < 1e-6:
            break
    dens = np.exp(np.clip(CubicSpline(centre, phi, bc_type="natural")(x), -700, 700))
    seg = 0.5 * (dens[1:] + dens[:-1]) * np.diff(x)
    m = np.bincount(owner[:-1], weights=seg, minlength=len(q))
    seg = seg * (q / np.maximum(m, 1e-300))[owner[:-1]]  # exact masses per bin
    cum = np.r_[0.0, np.cumsum(seg)]
    return lambda e: np.interp(e, x, cum)


class _Scorer:
    """Damped Fisher scoring of the spectral model on the used channels of the group counts ``n``:

        mu_gk = A_g (M_S(a_g) q_S + z_g M_F(a_g) c)_k + B_g (M_B(a_g) q_B)_k,    a_g = 1 + gamma / 100 * t_g / 60

    with log parameters for the template masses q and the amplitudes A, B, and linear ones for the (signed)
    shape nuisance c and the drift gamma (percent per minute). M_T(a) = response(a) @ within-channel shape_T.
    """

    def __init__(self, edges: np.ndarray, t: np.ndarray, n: np.ndarray, used: np.ndarray,
                 templates: tuple[np.ndarray, np.ndarray], fix_s: bool, tau: np.ndarray):
        self.edges, self.t, self.n, self.used, self.fix_s = edges, t, n, used, fix_s
        self.tau = np.asarray(tau, dtype=float)
        self.tt = (t - t.mean()) / max(float(t.std()), 1e-9)
        self.lo, self.hi = energy_bins(edges, 1)
        #: within-channel shapes, fixed: smooth densities with each template's channel masses
        self.cdfs = [histospline_cdf(self.lo, self.hi, q) for q in templates]
        self.f_lo = [cdf(self.lo) for cdf in self.cdfs]
        self.f_hi = [cdf(self.hi) for cdf in self.cdfs]
        self.masses = [np.maximum(q, 0.0) for q in templates]
        self.gmax = np.inf
        self._cache: dict[int, tuple[np.ndarray, ...]] = {}
        #: the last drift interpolated and its matrices: a scoring iteration asks for one drift several times
        #: (Jacobian, model, step), each answer read only
        self._last: tuple[float, tuple[np.ndarray, ...]] | None = None

    def background(self, bb: np.ndarray) -> np.ndarray:
        """(G,) background amplitudes: duration x exp(b0 + b1 t~), t~ the standardised group time."""
        return self.tau * np.exp(bb[0] + bb[1] * self.tt)

    def mats(self, gamma: float) -> tuple[np.ndarray, ...]:
        """(M_S, M_B, M_F) at drift gamma, each (G, channels, energy bins): the fraction of energy bin j
        recorded in channel k, integrated exactly over the stretched channel boundaries (no sub-bins: a
        piecewise-constant sub-bin leaks mass over an edge where the density has fallen to zero)."""
        # exact on a grid of drifts GAMMA_STEP apart, linear in between (the scoring steps and the derivative's
        # finite difference then reuse a few grid points instead of integrating anew at every trial drift)
        gamma = float(gamma)
        if self._last is not None and self._last[0] == gamma:
            return self._last[1]
        u = gamma / GAMMA_STEP
        i = int(np.floor(u))
        w = u - i
        lo_m, hi_m = self._exact(i), self._exact(i + 1)
        out = lo_m if w == 0.0 else tuple(x + w * (y - x) for x, y in zip(lo_m, hi_m, strict=True))
        self._last = (gamma, out)
        return out

    def _exact(self, i: int) -> tuple[np.ndarray, ...]:
        key = i
        if key not in self._cache:
            if len(self._cache) > 256:
                self._cache.clear()
            a = 1.0 + i * GAMMA_STEP / 100.0 * self.t / 60.0
            c = self.edges[None, :] / a[:, None]
            c[:, -1] = np.inf
            # a boundary below bin j counts as lo_j, above it as hi_j, inside as itself: (G, 33, 32), the
            # cumulative masses evaluated at the 33 boundaries only
            below = c[:, :, None] <= self.lo[None, None, :]
            above = c[:, :, None] >= self.hi[None, None, :]
            X = np.where(below, self.lo[None, None, :], np.where(above, self.hi[None, None, :], c[:, :, None]))
            flat = np.diff(X, axis=1) / (self.hi - self.lo)[None, None, :]
            out = []
            for cdf, m, f_lo, f_hi in zip(self.cdfs, self.masses, self.f_lo, self.f_hi, strict=True):
                ok = m > 1e-12 * m.max()
                FX = np.where(below, f_lo[None, None, :], np.where(above, f_hi[None, None, :], cdf(c)[:, :, None]))
                P = np.diff(FX, axis=1) / np.where(ok, m, 1.0)[None, None, :]
                out.append(np.where(ok[None, None, :], np.clip(P, 0.0, None), flat))
            self._cache[key] = (*out, flat)
        return self._cache[key]

    def parts(self, p: dict, z: np.ndarray | None, gamma: float | None = None, full: bool = False) -> tuple:
        """(source, background) channel masses per group: M_S q_S + z_g M_F c (the scattered continuum,
        growing with distance) and M_B q_B."""
        Ms, Mb, Mf = self.mats(p["gamma"] if gamma is None else gamma)
        us = Ms @ p["qs"]
        if z is not None and p["c"] is not None:
            us = us + z[:, None] * (Mf @ p["c"])
        ub = Mb @ p["qb"]
        if not full:
            us, ub = us[:, self.used], ub[:, self.used]
        return us, ub

    def mu(self, p: dict, z: np.ndarray | None, gamma: float | None = None, full: bool = False) -> np.ndarray:
        us, ub = self.parts(p, z, gamma, full)
        return p["a_s"][:, None] * us + p["a_b"][:, None] * ub

    def nll(self, p: dict, z: np.ndarray | None) -> float:
        mu = self.mu(p, z)
        if (mu < 0).any() or ((mu <= 0) & (self.n > 0)).any():
            return np.inf
        return _poisson_nll(mu, self.n)

    def jacobian(self, p: dict, z: np.ndarray | None, gamma_free: bool) -> tuple[np.ndarray, list[str]]:
        """(cells, parameters) d mu / d (log q_S, c, log q_B, log A, log B, gamma), and the blocks' names.

        Gauge freedoms are removed so that the Fisher matrix is regular: each template's largest mass is held
        (its log masses and the amplitudes trade a common factor), and so is c there (a constant c only
        rescales the amplitudes)."""
        G, K = self.n.shape
        before, u, after, names = self._columns(p, z, gamma_free)
        blk = np.zeros((G, K, G))
        blk[np.arange(G), :, np.arange(G)] = u
        return np.hstack([*before, blk.reshape(G * K, G), *after]), names

    def normal_equations(self, p: dict, z: np.ndarray | None, gamma_free: bool, m: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """The scoring step's Fisher matrix J^T diag(1/m) J and gradient J^T (1 - n/m) at the expected counts
        ``m`` (cells), with J = :meth:`jacobian`, and the blocks' names. The group amplitudes' block of J is
        diagonal by group, so its products are sums over each group's channels: the dense (cells, groups) block
        is never built (it was most of J, and of the product's cost)."""
        G, K = self.n.shape
        before, u, after, names = self._columns(p, z, gamma_free)
        D = np.hstack([*before, *after])  # (cells, dense parameters)
        w = 1.0 / m
        r = 1.0 - self.n.ravel() / m
        Dw = D * w[:, None]
        uw = u * w.reshape(G, K)
        nb = sum(c.shape[1] for c in before)
        nd = D.shape[1]
        idx = np.r_[np.arange(nb), nb + G + np.arange(nd - nb)]  # the dense columns' places among all
        F = np.zeros((nd + G, nd + G))
        F[np.ix_(idx, idx)] = Dw.T @ D
        cross = np.einsum("gkd,gk->dg", D.reshape(G, K, nd), uw)  # (dense, groups)
        F[idx, nb:nb + G] = cross
        F[nb:nb + G, idx] = cross.T
        F[np.arange(nb, nb + G), np.arange(nb, nb + G)] = (uw * u).sum(1)
        grad = np.zeros(nd + G)
        grad[idx] = D.T @ r
        grad[nb:nb + G] = (u * r.reshape(G, K)).sum(1)
        return F, grad, names

    def _columns(self, p: dict, z: np.ndarray | None, gamma_free: bool
                 ) -> tuple[list[np.ndarray], np.ndarray, list[np.ndarray], list[str]]:
        """The Jacobian's blocks: the dense columns before the group amplitudes (masses, nuisance), the
        amplitudes' values (G, K) (d mu_gk / d log A_g, zero off group g), the dense columns after them
        (background, drift), and the blocks' names in column order."""
        G, K = self.n.shape
        Ms, Mb = (M[:, self.used, :] for M in self.mats(p["gamma"])[:2])
        us, ub = self.parts(p, z)
        before, after, names = [], [], []

        def drop_max(blk: np.ndarray, q: np.ndarray) -> np.ndarray:
            return np.delete(blk, int(np.argmax(q)), axis=1)

        if not self.fix_s:
            before.append(drop_max((p["a_s"][:, None, None] * Ms * p["qs"][None, None, :]).reshape(G * K, -1),
                                   p["qs"]))
            names.append("qs")
        if z is not None and p["c"] is not None:
            Mf = self.mats(p["gamma"])[2][:, self.used, :]
            before.append(((p["a_s"] * z)[:, None, None] * Mf * p["c"][None, None, :]).reshape(G * K, -1))
            names.append("c")
        before.append(drop_max((p["a_b"][:, None, None] * Mb * p["qb"][None, None, :]).reshape(G * K, -1), p["qb"]))
        names.append("qb")
        names.append("a_s")
        # the background rate: log-linear in time, not free per group (free, it would follow a drift: a
        # drifting spectrum is to first order the source plus a second spectrum growing with time)
        jb = p["a_b"][:, None] * ub
        after.append(np.column_stack([jb.ravel(), (jb * self.tt[:, None]).ravel()]))
        names.append("bb")
        if gamma_free:
            h = 1e-3
            d = (self.mu(p, z, p["gamma"] + h) - self.mu(p, z, p["gamma"] - h)) / (2 * h)
            after.append(d.reshape(G * K, 1))
            names.append("gamma")
        return before, us * p["a_s"][:, None], after, names

    def at_bounds(self, p: dict, names: list[str]) -> np.ndarray:
        """(parameters,) -1 where a parameter sits on its lower bound (a mass or amplitude at its floor, c at
        floor), else 0, in the Jacobian's column order."""
        out = []
        for nm in names:
            if nm in ("gamma", "bb"):
                out.append(np.zeros(1 if nm == "gamma" else 2))
            elif nm == "c":
                out.append(np.where(p["c"] <= 1.001 * C_FLOOR, -1.0, 0.0))
            else:
                v = p[nm] if nm in ("a_s", "a_b") else np.delete(p[nm], int(np.argmax(p[nm])))
                out.append(np.where(v <= 1.001e-12 * p[nm].max(), -1.0, 0.0))
        return np.concatenate(out)

    def step(self, p: dict, names: list[str], delta: np.ndarray) -> dict:
        q = dict(p)
        i = 0
        for nm in names:
            m = 1 if nm == "gamma" else len(p[nm]) - (nm in ("qs", "qb"))
            d = delta[i:i + m]
            i += m
            if nm == "bb":
                q["bb"] = p["bb"] + np.clip(d, -3.0, 3.0)
                q["a_b"] = self.background(q["bb"])
            elif nm == "c":
                q["c"] = np.maximum(p["c"] * np.exp(np.clip(d, -3.0, 3.0)), C_FLOOR)
            elif nm == "gamma":
                q["gamma"] = float(np.clip(p["gamma"] + d[0], -self.gmax, self.gmax))
            else:  # floors keep masses away from denormals (which make every product slow)
                if nm in ("qs", "qb"):
                    d = np.insert(d, int(np.argmax(p[nm])), 0.0)
                q[nm] = np.maximum(p[nm] * np.exp(np.clip(d, -3.0, 3.0)), 1e-12 * p[nm].max())
        for tm, am in (("qs", "a_s"), ("qb", "a_b")):
            s = q[tm].sum()
            q[tm], q[am] = q[tm] / s, q[am] * s
            if tm == "qb":
                q["bb"] = q["bb"] + np.r_[np.log(s), 0.0]
        return q

    def fit(self, p: dict, z: np.ndarray | None, gamma_free: bool, iters: int = 200,
            tol: float = 1e-6) -> tuple[float, dict]:
        """Levenberg-Marquardt damped Fisher scoring from ``p``; stops when the Newton decrement (the
        decrease a full step would bring) is below ``tol``."""
        nll = self.nll(p, z)
        lam = 1e-3
        hist = [nll]
        restarts = 0
        for _ in range(iters):
            if len(hist) > 10 and hist[-11] - nll < 10 * tol:  # crawling: a flat direction, or over-damped
                if lam <= 1e-3 or restarts >= 3:
                    break
                lam, hist, restarts = 1e-4, hist[-1:], restarts + 1
            m = np.maximum(self.mu(p, z).ravel(), 1e-12)
            F_all, grad, names = self.normal_equations(p, z, gamma_free, m)
            # active set: a parameter on its bound that the gradient pushes further out stays where it is
            b = self.at_bounds(p, names)
            free = ~(((b < 0) & (grad > 0)) | ((b > 0) & (grad < 0)))
            gf = grad[free]
            F = F_all[np.ix_(free, free)]
            dg = np.diag(F).copy()
            reg = 1e-9 * dg.max() * np.eye(len(dg))
            try:
                if gf @ np.linalg.solve(F + reg, gf) < 2 * tol:
                    break
            except np.linalg.LinAlgError:
                pass
            improved = False
            for _ in range(12):
                try:
                    df = np.linalg.solve(F + lam * np.diag(dg) + reg, -gf)
                except np.linalg.LinAlgError:
                    lam *= 8
                    continue
                delta = np.zeros(len(grad))
                delta[free] = df
                q = self.step(p, names, delta)
                nll2 = self.nll(q, z)
                if nll2 <= nll:
                    improved = True
                    lam = max(lam / 5, 1e-9)
                    break
                lam *= 8
            if not improved:
                if lam <= 1e-3 or restarts >= 3:
                    break
                lam, restarts = 1e-4, restarts + 1
                continue
            p, nll = q, nll2
            hist.append(nll)
        return nll, p

    def variance(self, p: dict, z: np.ndarray | None) -> float:
        """Variance of the drift estimate from the Fisher information (pseudo-inverse: the template masses'
        normalisation is a free direction of the log parameters, orthogonal to the drift)."""
        J, _ = self.jacobian(p, z, gamma_free=True)
        m = np.maximum(self.mu(p, z).ravel(), 1e-12)
        F = (J / m[:, None]).T @ J
        sc = np.sqrt(np.maximum(np.diag(F), 1e-300))
        return float(np.linalg.pinv(F / sc[:, None] / sc[None, :], rcond=1e-10)[-1, -1] / sc[-1] ** 2)
