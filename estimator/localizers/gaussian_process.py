"""Gaussian-process field reconstruction and peak analysis (paper 001, Algorithm 2 and sec. 2.2.3).

Algorithm 2: the measurement points x_i (dwell positions, x-y) and their readings y_i (mean count rate
minus the operator's background) train a GP with the squared-exponential kernel (eq. 12)

    k(x, x') = sigma_f^2 exp(-1/2 (x - x')^T M^-1 (x - x')),  M = diag(l^2)

plus noise (eq. 6-7): the known Poisson variance of each reading and a fitted white noise delta_n^2. The
hyperparameters (sigma_f, l, delta_n) maximise the log marginal likelihood (eq. 13), multi-start L-BFGS-B
on their logarithms; the mean function is the constant mean of the readings. The posterior mean (eq. 10)
on an m x n grid over ``scenario.bounds`` (step ``grid_step``) is the reconstructed field.

Peak analysis (eq. 14-15): a point source makes a peak of the field at its position, so the sources are the
local maxima of the reconstructed field: the highest one (``n_sources=1``), the two highest (``2``), or
with ``"auto"`` every local maximum reaching ``peak_fraction`` of the highest (at most ``max_sources``).
The paper's GP is on the raw field (``transform="none"``); ``"log"`` models log(rate) instead, whose
inverse-square peak is far better matched by a stationary SE kernel (the default, see docs/localizers.md).

Intensity (not part of paper 001, which only locates): given the peak positions, ``cps_at_1m`` follows by
weighted least squares of the readings on the inverse-square gains. Position uncertainty: the spread of
the arg-max of ``n_posterior_samples`` posterior draws of the field in a window around each peak (the
GP's own uncertainty about where the peak is). No CRLB.

Measurement points are the dwells; with ``use_transit`` (``"auto"``: when the flight spent more time in
transit than dwelling, i.e. a survey) the transit frames are added as ``chunk_s`` chunks at their mean pose.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import linalg, optimize
from scipy.ndimage import maximum_filter

from estimator.dwell_summary import summarize_chunks, summarize_dwells
from estimator.localizers.base import Localizer, source_dict
from radseek.count_model import expected_rate
from radseek.dataset import Frames, Scenario

__all__ = ["GaussianProcessLocalizer", "GaussianProcess", "find_peaks"]


def _se_kernel(a: np.ndarray, b: np.ndarray, sigma_f: float, length: float) -> np.ndarray:
    d2 = ((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)
    return sigma_f**2 * np.exp(-0.5 * d2 / length**2)


class GaussianProcess:
    """Minimal GP regression with the SE kernel (eq. 5-13); ``noise_var`` is the known per-point variance."""

    def __init__(self, x: np.ndarray, y: np.ndarray, noise_var: np.ndarray, length_bounds=(0.2, 20.0),
                 n_restarts: int = 4, seed: int = 0):
        self.x = np.asarray(x, dtype=float)
        self.y = np.asarray(y, dtype=float)
        self.noise_var = np.asarray(noise_var, dtype=float)
        self.mean = float(self.y.mean())
        yc = self.y - self.mean
        scale = float(np.std(yc)) or 1.0
        rng = np.random.default_rng(seed)

        def nlml(logp: np.ndarray) -> float:
            sf, ln, dn = np.exp(logp)
            k = _se_kernel(self.x, self.x, sf, ln) + np.diag(self.noise_var + dn**2 + 1e-9 * scale**2)
            try:
                c = linalg.cho_factor(k, lower=True)
            except linalg.LinAlgError:
                return 1e25
            alpha = linalg.cho_solve(c, yc)
            # eq. 13 (negated)
            return float(0.5 * yc @ alpha + np.log(np.diag(c[0])).sum() + 0.5 * len(yc) * np.log(2 * np.pi))

        lo = np.log([1e-3 * scale, length_bounds[0], 1e-4 * scale])
        hi = np.log([1e2 * scale, length_bounds[1], 10 * scale])
        best = None
        starts = [np.log([scale, np.clip(1.5, *length_bounds), 0.05 * scale])]
        starts += [rng.uniform(lo, hi) for _ in range(n_restarts)]
        for s0 in starts:
            r = optimize.minimize(nlml, s0, method="L-BFGS-B", bounds=list(zip(lo, hi, strict=True)))
            if best is None or r.fun < best.fun:
                best = r
        self.sigma_f, self.length, self.delta_n = (float(v) for v in np.exp(best.x))
        self.log_marginal_likelihood = -float(best.fun)
        k = _se_kernel(self.x, self.x, self.sigma_f, self.length)
        k += np.diag(self.noise_var + self.delta_n**2 + 1e-9 * scale**2)
        self._chol = linalg.cho_factor(k, lower=True)
        self._alpha = linalg.cho_solve(self._chol, yc)

    def predict_mean(self, xs: np.ndarray) -> np.ndarray:
        """Posterior mean (eq. 10) at ``xs`` (M, 2)."""
        return self.mean + _se_kernel(xs, self.x, self.sigma_f, self.length) @ self._alpha

    def predict(self, xs: np.ndarray, cov: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean (eq. 10) and variance or full covariance (eq. 11) at ``xs`` (M, 2)."""
        ks = _se_kernel(xs, self.x, self.sigma_f, self.length)
        m = self.mean + ks @ self._alpha
        v = linalg.cho_solve(self._chol, ks.T)
        if cov:
            return m, _se_kernel(xs, xs, self.sigma_f, self.length) - ks @ v
        return m, np.clip(self.sigma_f**2 - (ks * v.T).sum(1), 0.0, None)


def find_peaks(field: np.ndarray) -> list[tuple[int, int]]:
    """Grid indices of the strict local maxima of a 2-D field (3 x 3 neighbourhood), highest first."""
    mx = maximum_filter(field, size=3, mode="nearest")
    idx = np.argwhere((field >= mx) & (field > field.min()))
    order = np.argsort(field[idx[:, 0], idx[:, 1]])[::-1]
    return [tuple(int(v) for v in idx[i]) for i in order]


class GaussianProcessLocalizer(Localizer):
    """Paper 001 GP field reconstruction + peak analysis (see module docstring)."""

    name = "gp"

    def __init__(self, n_sources: int | str = 1, max_sources: int = 2, peak_fraction: float = 0.3,
                 transform: str = "log", grid_step: float = 0.05, use_transit: bool | str = "auto",
                 chunk_s: float = 5.0, n_restarts: int = 4, n_posterior_samples: int = 200, min_frames: int = 5,
                 seed: int = 0):
        self.n_sources = n_sources
        self.max_sources = max_sources
        self.peak_fraction = peak_fraction
        self.transform = transform
        self.grid_step = grid_step
        self.use_transit = use_transit
        self.chunk_s = chunk_s
        self.n_restarts = n_restarts
        self.n_posterior_samples = n_posterior_samples
        self.min_frames = min_frames
        self.seed = seed

    def _readings(self, frames: Frames, bg: float) -> tuple[Any, np.ndarray, np.ndarray]:
        transit = self.use_transit
        if transit == "auto":  # a survey (more time in transit than dwelling) is read along the path
            transit = frames.duration[frames.dwell < 0].sum() > frames.duration[frames.dwell >= 0].sum()
        meas = (summarize_chunks(frames, self.chunk_s) if transit
                else summarize_dwells(frames, min_frames=self.min_frames))
        rate, sig = meas.rate, meas.rate_sigma
        if self.transform == "none":
            return meas, rate - bg, sig**2
        if self.transform == "log":
            r = np.maximum(rate, 1.0 / meas.duration)
            return meas, np.log(r), (sig / r) ** 2
        raise ValueError(f"transform must be 'none' or 'log', got {self.transform!r}")

    def _fit(self, frames: Frames, scenario: Scenario) -> None:
        bg = float(scenario.background_cps)
        meas, y, var = self._readings(frames, bg)
        if len(meas) < 3:
            raise ValueError(f"GP reconstruction needs >= 3 measurement points, got {len(meas)}")
        xy = meas.positions[:, :2]
        span = float(np.max(scenario.bounds_max[:2] - scenario.bounds_min[:2]))
        gp = GaussianProcess(xy, y, var, length_bounds=(0.3, max(span, 1.0)), n_restarts=self.n_restarts,
                             seed=self.seed)
        lo, hi = scenario.bounds_min[:2], scenario.bounds_max[:2]
        gx = np.arange(lo[0], hi[0] + 1e-9, self.grid_step)
        gy = np.arange(lo[1], hi[1] + 1e-9, self.grid_step)
        mesh = np.stack(np.meshgrid(gx, gy, indexing="ij"), axis=-1).reshape(-1, 2)
        field = np.concatenate([gp.predict_mean(mesh[i:i + 20000]) for i in range(0, len(mesh), 20000)])
        field = field.reshape(len(gx), len(gy))
        peaks = find_peaks(field)
        if not peaks:
            peaks = [tuple(int(v) for v in np.unravel_index(np.argmax(field), field.shape))]
        if self.n_sources == "auto":
            base = float(np.median(field))
            top = field[peaks[0]] - base
            chosen = [p for p in peaks if field[p] - base >= self.peak_fraction * top][: int(self.max_sources)]
        else:
            chosen = peaks[: int(self.n_sources)]
        positions = np.array([[gx[i], gy[j]] for i, j in chosen])
        rng = np.random.default_rng(self.seed)
        pos_cov = [self._peak_covariance(gp, p, rng) for p in positions]
        # intensities by weighted least squares on the inverse-square gains at the found positions
        z_s = scenario.source_z
        d2 = ((meas.positions[:, None, :2] - positions[None]) ** 2).sum(-1) + (meas.positions[:, None, 2] - z_s) ** 2
        g = expected_rate(d2, 1.0)
        w = 1.0 / (meas.rate_sigma**2 + (0.05 * np.abs(meas.rate - bg)) ** 2)
        a = (g * w[:, None]).T @ g
        b = (g * w[:, None]).T @ (meas.rate - bg)
        try:
            s = np.linalg.solve(a, b)
            s_cov = np.linalg.inv(a)
        except np.linalg.LinAlgError:
            s, s_cov = np.zeros(len(positions)), np.eye(len(positions))
        m = len(positions)
        cov = np.zeros((4 * m, 4 * m))
        self.sources_ = []
        for i in range(m):
            self.sources_.append(source_dict(positions[i, 0], positions[i, 1], z_s, max(s[i], 0.0)))
            o = 4 * i
            cov[o:o + 2, o:o + 2] = pos_cov[i]
            cov[o + 2, o + 2] = 1e-9
            for j in range(m):
                cov[o + 3, 4 * j + 3] = s_cov[i, j]
        self.covariance_ = cov
        self.background_ = bg
        self.crlb_ = None
        self.gp_ = gp
        self.field_ = (gx, gy, field)
        self.info_ = {"sigma_f": gp.sigma_f, "length_m": gp.length, "delta_n": gp.delta_n,
                      "log_marginal_likelihood": gp.log_marginal_likelihood, "n_peaks": len(peaks),
                      "n_measurements": len(meas), "transform": self.transform}

    def _peak_covariance(self, gp: GaussianProcess, peak: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Covariance of the arg-max of posterior field draws in a window around ``peak``."""
        floor = (self.grid_step**2) / 12 * np.eye(2)
        if not self.n_posterior_samples:
            return floor
        half = min(1.5, 2 * gp.length)
        step = max(self.grid_step, half / 15)
        ax = np.arange(-half, half + 1e-9, step)
        win = peak + np.stack(np.meshgrid(ax, ax, indexing="ij"), axis=-1).reshape(-1, 2)
        m, c = gp.predict(win, cov=True)
        try:
            lchol = np.linalg.cholesky(c + 1e-9 * np.trace(c) / len(c) * np.eye(len(c)) + 1e-12 * np.eye(len(c)))
        except np.linalg.LinAlgError:
            return floor
        draws = m[None] + rng.standard_normal((self.n_posterior_samples, len(m))) @ lchol.T
        am = win[np.argmax(draws, axis=1)]
        return np.cov(am.T) + floor
