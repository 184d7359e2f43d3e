"""Multi-source particle filter (paper 004, ch. 3-5): multiple-landmark intensities, roulette resampling with
jitter, sequential source discovery with subtraction, intensity separation and wall attenuation.

Measurements are the per-dwell mean rates z_k at p_k (:func:`estimator.dwell_summary.summarize_dwells`).
A particle is a candidate position (x, y) on the floor z = ``scenario.source_z`` (eq. 3.2); its intensity
is not sampled but computed from all measurements so far (multiple-landmark estimate, eq. 3.11, with the
wall-attenuation form eq. 5.19 when ``wall_mu_per_m`` > 0 and the scenario maps walls):

    I^i = sum_k (z'_k - lambda_b) / sum_k exp(-mu L_ik) d_ik^-2

(``n_landmarks`` limits the sums to the most recent measurements, as the thesis does with walls). z'_k are
the measurements minus the sources already found (eq. 4.11). The weight of a particle is the product of
the Gaussian-approximated Poisson likelihoods of all measurements (eq. 3.12-3.15, in counts:
N(n_k; mu_k, mu_k) with mu_k = T_k (I^i g_ik + lambda_b)); since I^i is recomputed from all data, the
product is evaluated over the whole history at every step (equivalent to Algorithm 3.1's recursive
product for the current intensities). Extensions: the squared residual has a Huber tail beyond
``robust_sigma`` (a reading dominated by another source must not drag this one), and ``intensity="wls"``
replaces eq. 3.11 by the likelihood-optimal closed form (sec. 3.2.2.2's "optimisation method").

Resampling (sec. 3.2.4): the ``resample_fraction`` lowest-weight particles, and any of zero weight, are
replaced by roulette-wheel draws among the others plus Gaussian jitter N(0, mag^2) (eq. 3.16-3.17), with mag
decreasing linearly from ``jitter_start`` to ``jitter_end`` over the measurements. The estimate is the
weighted mean of the ``top_fraction`` highest-weight particles (sec. 3.2.3).

Several sources (sec. 4.3): after a pass over the flight the source found is added to the partial map and
subtracted from the measurements (eq. 4.11); a new pass looks for the next one while some residual
reading still exceeds the background by ``detect_sigma`` (up to ``max_sources``). The apparent intensities
are then separated (eq. 4.16): the thesis solves the M x M linear system I'_i = sum_j I_j / d_ij^2 + lambda_b
(:func:`separate_intensities`); with measurements at arbitrary poses the same coupling is the weighted
least-squares system (G^T W G) I = G^T W (z - lambda_b), G_kj = exp(-mu L_kj) / d_kj^2, which the
localizer solves (it reduces to eq. 4.16 when each source has one measurement at 1 m). A later source whose
separated intensity is below 3 sigma is dropped (a residue of model mismatch, not a source).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from estimator.dwell_summary import DwellSummary, summarize_dwells
from estimator.localizers.base import Localizer, source_dict
from radseek.count_model import expected_rate
from radseek.dataset import Frames, Scenario
from radseek.geometry import path_lengths, wall_arrays

__all__ = ["MultiSourceParticleFilter", "landmark_intensity", "separate_intensities"]


def _gain(px: np.ndarray, py: np.ndarray, z_s: float, pos: np.ndarray, walls: np.ndarray, mu: float) -> np.ndarray:
    """(P, K) geometric gain exp(-mu L) / d^2 of candidate sources (P,) for measurement positions (K, 3):
    the rate of a unit source (:func:`radseek.count_model.expected_rate`)."""
    d2 = (px[:, None] - pos[None, :, 0]) ** 2 + (py[:, None] - pos[None, :, 1]) ** 2 + (z_s - pos[None, :, 2]) ** 2
    attenuation = None
    if mu > 0 and len(walls):
        src = np.stack([px, py, np.full_like(px, z_s)], axis=-1)[:, None, :]
        attenuation = np.exp(-mu * path_lengths(src, pos[None, :, :], walls))
    return expected_rate(d2, 1.0, attenuation=attenuation)


def landmark_intensity(z: np.ndarray, gain: np.ndarray, background: float) -> np.ndarray:
    """Paper 004 eq. 3.11 / 5.19: I = sum_k (z_k - lambda_b) / sum_k g_k, per particle (rows of ``gain``)."""
    return np.clip((np.sum(z - background)) / np.maximum(gain.sum(axis=-1), 1e-12), 0.0, None)


def separate_intensities(positions: np.ndarray, apparent: np.ndarray, background: float) -> np.ndarray:
    """Paper 004 eq. 4.12-4.16: true intensities I from apparent ones I' = I_i + sum_j!=i I_j / d_ij^2 + lambda_b.

    ``positions`` (M, 2 or 3), ``apparent`` (M,). Solves the M x M linear system (Gauss-Jordan in the thesis).
    """
    p = np.asarray(positions, dtype=float)
    d2 = ((p[:, None, :] - p[None, :, :]) ** 2).sum(-1)
    a = np.where(np.eye(len(p), dtype=bool), 1.0, 1.0 / np.maximum(d2, 1e-12))
    return np.linalg.solve(a, np.asarray(apparent, dtype=float) - background)


class MultiSourceParticleFilter(Localizer):
    """Paper 004 multi-source particle filter (see module docstring)."""

    name = "multi-pf"  # partial_fit refits: every new dwell changes all particles' eq. 3.11 intensities

    def __init__(self, n_particles: int = 5000, max_sources: int = 2, detect_sigma: float = 8.0,
                 resample_fraction: float = 0.3, jitter_start: float = 0.5, jitter_end: float = 0.05,
                 top_fraction: float = 0.1, n_landmarks: int | None = None, wall_mu_per_m: float = 0.0,
                 model_error: float = 0.05, n_passes: int = 3, robust_sigma: float | None = 5.0,
                 intensity: str = "landmarks", min_frames: int = 5, seed: int = 0):
        self.n_particles = n_particles
        self.max_sources = max_sources
        self.detect_sigma = detect_sigma
        self.resample_fraction = resample_fraction
        self.jitter_start = jitter_start
        self.jitter_end = jitter_end
        self.top_fraction = top_fraction
        self.n_landmarks = n_landmarks
        self.wall_mu_per_m = wall_mu_per_m
        self.model_error = model_error
        self.n_passes = n_passes
        self.robust_sigma = robust_sigma
        self.intensity = intensity
        self.min_frames = min_frames
        self.seed = seed

    # --------------------------------------------------------------------------- one source

    def _loglik(self, px: np.ndarray, py: np.ndarray, meas: DwellSummary, zprime: np.ndarray, bg: float
                ) -> tuple[np.ndarray, np.ndarray]:
        """Per-particle intensities (eq. 3.11/5.19) and log-likelihood of all measurements (eq. 3.14)."""
        g = _gain(px, py, self._z_s, meas.positions, self._walls, self.wall_mu_per_m)
        sel = slice(None) if not self.n_landmarks else slice(-int(self.n_landmarks), None)
        if self.intensity == "landmarks":
            intensity = landmark_intensity(zprime[sel], g[:, sel], bg)
        else:
            # sec. 3.2.2.2 "optimization method": the likelihood-optimal I, here in closed form (weighted
            # least squares with the measurement variances), robustified by one Huber reweighting
            zs, gs, t = zprime[sel], g[:, sel], meas.duration[sel]
            v = np.maximum(zs, bg) / t + (self.model_error * np.abs(zs - bg)) ** 2
            wk = np.broadcast_to(1.0 / v, gs.shape)
            intensity = np.clip((gs * wk * (zs - bg)).sum(1) / np.maximum((gs * gs * wk).sum(1), 1e-300), 0, None)
            if self.robust_sigma:
                r = np.abs(zs - bg - intensity[:, None] * gs) / np.sqrt(v)
                wk = wk * np.minimum(1.0, self.robust_sigma / np.maximum(r, 1e-12))
                intensity = np.clip((gs * wk * (zs - bg)).sum(1) / np.maximum((gs * gs * wk).sum(1), 1e-300), 0,
                                    None)
        rate = intensity[:, None] * g + bg
        mu = rate * meas.duration
        # Gaussian approximation of the Poisson (eq. 3.13) in counts, widened by a relative model error
        var = mu + (self.model_error * (mu - bg * meas.duration)) ** 2
        n = zprime * meas.duration
        r2 = (n - mu) ** 2 / var
        if self.robust_sigma:
            # Huber loss beyond robust_sigma: a reading another source dominates does not drag this one
            c = float(self.robust_sigma)
            r2 = np.where(r2 < c * c, r2, 2 * c * np.sqrt(r2) - c * c)
        ll = -0.5 * (r2 + np.log(var)).sum(axis=1)
        return intensity, ll

    def _find_one(self, meas: DwellSummary, zprime: np.ndarray, bg: float, rng: np.random.Generator
                  ) -> dict[str, Any]:
        lo, hi = self._lo, self._hi
        n = int(self.n_particles)
        px = rng.uniform(lo[0], hi[0], n)
        py = rng.uniform(lo[1], hi[1], n)
        k_total = len(meas)
        steps = 0
        n_steps = max(k_total * self.n_passes, 1)
        w = np.full(n, 1.0 / n)
        intensity = np.zeros(n)
        for _ in range(self.n_passes):
            for k in range(1, k_total + 1):
                part = meas.select(np.arange(k))
                intensity, ll = self._loglik(px, py, part, zprime[:k], bg)
                ll -= ll.max()
                w = np.exp(ll)
                w /= w.sum()
                steps += 1
                mag = self.jitter_start + (self.jitter_end - self.jitter_start) * steps / n_steps
                px, py = self._resample(px, py, w, mag, rng)
        intensity, ll = self._loglik(px, py, meas, zprime, bg)
        ll -= ll.max()
        w = np.exp(ll)
        w /= w.sum()
        top = np.argsort(w)[::-1][: max(int(self.top_fraction * n), 1)]
        wt = w[top] / w[top].sum()
        state = np.stack([px[top], py[top], intensity[top]], axis=1)
        mean = wt @ state
        dev = state - mean
        cov = (dev * wt[:, None]).T @ dev
        return {"mean": mean, "cov": cov, "particles": np.stack([px, py], axis=1), "weights": w}

    def _resample(self, px: np.ndarray, py: np.ndarray, w: np.ndarray, mag: float, rng: np.random.Generator
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Replace the lowest-weight fraction (and zero weights) by roulette draws + N(0, mag^2) (eq. 3.16-3.17)."""
        n = len(w)
        order = np.argsort(w)
        n_low = max(int(self.resample_fraction * n), int((w <= 1e-300).sum()))
        n_low = min(n_low, n - 1)
        low, high = order[:n_low], order[n_low:]
        wh = w[high] / w[high].sum()
        targets = high[np.minimum(np.searchsorted(np.cumsum(wh), rng.random(n_low)), len(high) - 1)]
        px, py = px.copy(), py.copy()
        px[low] = np.clip(px[targets] + rng.normal(0, mag, n_low), self._lo[0], self._hi[0])
        py[low] = np.clip(py[targets] + rng.normal(0, mag, n_low), self._lo[1], self._hi[1])
        return px, py

    def _contribution(self, m: np.ndarray, meas: DwellSummary, intensity: float) -> np.ndarray:
        """Rate a source at (x, y) = m[:2] of ``intensity`` adds at every measurement (partial map, eq. 4.11)."""
        g = _gain(np.array([m[0]]), np.array([m[1]]), self._z_s, meas.positions, self._walls, self.wall_mu_per_m)
        return max(float(intensity), 0.0) * g[0]

    def _separate(self, found: list[dict[str, Any]], meas: DwellSummary, z: np.ndarray, sigma: np.ndarray,
                  bg: float) -> tuple[np.ndarray, np.ndarray]:
        """Intensity separation (eq. 4.16 generalised to arbitrary poses): weighted least squares, and its cov."""
        pos = np.array([f["mean"][:2] for f in found])
        g = _gain(pos[:, 0], pos[:, 1], self._z_s, meas.positions, self._walls, self.wall_mu_per_m).T  # (K, M)
        wls = 1.0 / sigma**2
        a = (g * wls[:, None]).T @ g
        b = (g * wls[:, None]).T @ (z - bg)
        try:
            return np.linalg.solve(a, b), np.linalg.inv(a)
        except np.linalg.LinAlgError:
            return np.array([f["mean"][2] for f in found]), np.diag([f["cov"][2, 2] for f in found])

    # ------------------------------------------------------------------------------ fitting

    def _fit(self, frames: Frames, scenario: Scenario) -> None:
        rng = np.random.default_rng(self.seed)
        self._z_s = scenario.source_z
        self._lo, self._hi = scenario.bounds_min, scenario.bounds_max
        self._walls = wall_arrays(scenario.walls)
        meas = summarize_dwells(frames, min_frames=self.min_frames)
        if len(meas) < 3:
            raise ValueError(f"multi-source particle filter needs >= 3 dwell points, got {len(meas)}")
        bg = float(scenario.background_cps)
        z = meas.rate
        sigma = np.sqrt(meas.rate_sigma**2 + (0.05 * bg) ** 2)
        found: list[dict[str, Any]] = []
        zprime = z.copy()
        for _ in range(int(self.max_sources)):
            excess = (zprime - bg) / np.sqrt(sigma**2 + (self.model_error * np.abs(zprime - bg)) ** 2)
            if found and excess.max() < self.detect_sigma:
                break
            found.append(self._find_one(meas, zprime, bg, rng))
            # eq. 4.11: subtract the partial map of the sources found so far (apparent intensities)
            zprime = zprime - self._contribution(found[-1]["mean"], meas, found[-1]["mean"][2])
        intensities, i_cov = self._separate(found, meas, z, sigma, bg)
        # drop sources whose separated intensity is not significant (a residue of model mismatch)
        keep = [i for i in range(len(found)) if i == 0 or intensities[i] > 3 * np.sqrt(max(i_cov[i, i], 0))]
        if len(keep) < len(found):
            found = [found[i] for i in keep]
            intensities, i_cov = self._separate(found, meas, z, sigma, bg)
        self.sources_ = []
        cov = np.zeros((4 * len(found), 4 * len(found)))
        for i, f in enumerate(found):
            self.sources_.append(source_dict(f["mean"][0], f["mean"][1], self._z_s, max(intensities[i], 0.0)))
            o = 4 * i
            cov[o:o + 2, o:o + 2] = f["cov"][:2, :2]
            cov[o + 2, o + 2] = 1e-9
            cov[o + 3, o + 3] = i_cov[i, i]
        for i in range(len(found)):
            for j in range(len(found)):
                if i != j:
                    cov[4 * i + 3, 4 * j + 3] = i_cov[i, j]
        self.covariance_ = cov
        self.background_ = bg
        self.crlb_ = None
        self.particles_ = [f["particles"] for f in found]
        self.weights_ = [f["weights"] for f in found]
        self.info_ = {"n_sources": len(found), "apparent_intensities": [float(f["mean"][2]) for f in found],
                      "n_measurements": len(meas)}
