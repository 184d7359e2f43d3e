"""SIR particle filter for one source (paper 000, Algorithm 1), vectorised numpy over particles.

State per particle (paper 000 eq. 12): source position (x, y) on the floor z = ``scenario.source_z``,
activity A (``cps_at_1m``) and background Bg. Prior (eq. 11-12): x, y ~ U(scenario bounds),
A ~ Gamma(shape ``activity_shape``, scale ``activity_scale``) (paper: alpha = 2, beta = 6000),
Bg ~ U(``background_range`` x the operator's background estimate).

Measurement update (Algorithm 1 lines 4-8), for a measurement of ``counts`` in ``duration`` s at
detector position p (``update``):

    lambda_T = A / |p - s|^2 + Bg          (eq. 9; |p - s|^2 includes the height)
    lambda   = lambda_T exp(-a lambda_T)   (eq. 10, paralyzable dead time a = ``dead_time_s``)
    w       *= Poisson(counts; lambda T)   (``likelihood="poisson"``; ``"gaussian"`` is line 7's
                                            N(counts; lambda T, const2 lambda T) with const2 = ``gauss_const``)

then weights are normalised (eq. 8) and resampled with the low-variance (systematic) resampler of
Thrun et al. when the effective sample size drops below ``resample_threshold`` x N (1.0 = every step,
as in Algorithm 1). The paper omits the prediction step for a static source; without it a resampled
cloud can only lose diversity, so after each resampling the particles are roughened (Gordon et al.
1993): Gaussian jitter of sd ``roughening`` x (cloud range) x N^(-1/4) per state dimension.
With ``stop_variance`` set the filter stops updating once the total variance (eq. 13) falls below it
(Algorithm 1's loop condition).

Two further deviations make the filter usable on real flights. Adaptive tempering: when one measurement
would drop the ESS below ``temper_ess`` x N (a 1 s chunk near a strong source, or an ambiguous start such
as three collinear dwells), its likelihood is applied in powers phi_1 + phi_2 + ... = 1 with a
resample-and-roughen between them (at most ``max_tempering_steps``; 1 disables it); without it the cloud
can collapse onto one mirror mode and never recover. Model effects: with ``effects`` (names of
:mod:`estimator.model`) the expected counts come from ``MeasurementModel`` with the effect parameters
fixed at ``effect_params`` (calibrations, e.g. a wall's mu); the PF does not fit them. ``dead_time_s`` is
the same dead time as the ``dead_time`` effect (applied once; giving both with different values is an
error). With walls the
posterior can be multi-modal (sources behind a wall) and the filter may settle in the wrong mode; prefer
``mle`` or ``multi-pf`` there (docs/localizers.md).

``fit`` replays a flight as ~1 Hz measurements (paper 000 measures at 1 Hz): consecutive frames of one
dwell (or of transit) pooled into chunks of ``chunk_s`` seconds at their mean pose. ``history_`` keeps, per
update, the metrics of paper 000 (total variance eq. 13, entropy eq. 15, and the Gaussian fit used by
the KL divergence eq. 16) for ``radseek compare``.

Every expected count is :func:`radseek.count_model.expected_rate` (directly on the particle rows, or
through ``MeasurementModel`` with effects). Result: weighted mean and covariance of the cloud over
(x, y, z, A); ``crlb_`` is :func:`estimator.mle.crlb` (paper 004 eq. 5.3-5.7, Poisson Fisher information)
of the filter's own measurement model at the estimate over (x, y, A, Bg), projected on (x, y, z, A) with
z fixed; the history metrics are :mod:`estimator.metrics`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from estimator.dwell_summary import chunk_frames
from estimator.localizers.base import Localizer, source_dict
from estimator.metrics import entropy_from_cov, total_variance_from_cov, weighted_mean_cov
from estimator.mle import crlb
from estimator.model import MeasurementModel
from radseek.count_model import expected_rate
from radseek.dataset import Frames, Scenario
from radseek.topics import N_CHANNELS

__all__ = ["ParticleFilter", "low_variance_resample"]

#: the PF's state rows (x, y, A, Bg) as MeasurementModel parameters
STATE_PARAMS = ["x", "y", "cps_at_1m", "background_cps"]


def low_variance_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices drawn by the low-variance (systematic) resampler: one uniform u, N pointers (u + j) / N.

    Particle i receives as many copies as pointers fall in its slice of the cumulative weight, i.e.
    ceil(N c_i - u) - ceil(N c_{i-1} - u); computed by counting (O(N), no search).
    """
    n = len(weights)
    c = np.cumsum(weights)
    c *= n / c[-1]
    u = rng.random()
    upto = np.ceil(c - u).astype(np.int64)
    np.clip(upto, 0, n, out=upto)
    counts = np.diff(upto, prepend=0)
    return np.repeat(np.arange(n), counts)


class ParticleFilter(Localizer):
    """Paper 000 SIR particle filter (see module docstring)."""

    name = "pf"

    def __init__(self, n_particles: int = 100_000, activity_shape: float = 2.0, activity_scale: float = 6000.0,
                 background_range: tuple[float, float] = (0.7, 1.3), dead_time_s: float = 0.0,
                 likelihood: str = "poisson", gauss_const: float = 1.0, resample_threshold: float = 0.5,
                 roughening: float = 0.2, stop_variance: float | None = None, chunk_s: float = 1.0,
                 effects: Sequence[str] = (), effect_params: Mapping[str, float] | None = None,
                 max_tempering_steps: int = 8, temper_ess: float = 0.1, seed: int = 0):
        self.n_particles = n_particles
        self.activity_shape = activity_shape
        self.activity_scale = activity_scale
        self.background_range = background_range
        self.dead_time_s = dead_time_s
        self.likelihood = likelihood
        self.gauss_const = gauss_const
        self.resample_threshold = resample_threshold
        self.roughening = roughening
        self.stop_variance = stop_variance
        self.chunk_s = chunk_s
        self.effects = effects
        self.effect_params = effect_params
        self.max_tempering_steps = max_tempering_steps
        self.temper_ess = temper_ess
        self.seed = seed

    # ---------------------------------------------------------------------------- state

    def initialize(self, scenario: Scenario) -> ParticleFilter:
        """Draw the prior cloud (eq. 11-12) and clear the history."""
        if self.likelihood not in ("poisson", "gaussian"):
            raise ValueError(f"likelihood must be 'poisson' or 'gaussian', got {self.likelihood!r}")
        n = int(self.n_particles)
        self._build_model(scenario)
        rng = np.random.default_rng(self.seed)
        self.rng_ = rng
        self.scenario_ = scenario
        lo, hi = scenario.bounds_min, scenario.bounds_max
        b0 = scenario.background_cps
        self.state_ = np.empty((4, n))  # rows x, y, A, Bg (contiguous rows: fast vector ops)
        self.state_[0] = rng.uniform(lo[0], hi[0], n)
        self.state_[1] = rng.uniform(lo[1], hi[1], n)
        self.state_[2] = rng.gamma(self.activity_shape, self.activity_scale, n)
        self.state_[3] = rng.uniform(b0 * self.background_range[0], b0 * self.background_range[1], n)
        self.log_weights_ = np.zeros(n)
        self.weights_ = np.full(n, 1.0 / n)
        self.history_: list[dict[str, Any]] = []
        self.n_updates_ = 0
        self.n_resamples_ = 0
        self.converged_ = False
        self._meas: list[tuple[np.ndarray, float, float, float]] = []
        self._record(t=0.0)
        return self

    def _build_model(self, scenario: Scenario) -> None:
        """The filter's measurement model: the baseline plus ``effects``, with the dead time applied once."""
        if "second_source" in self.effects:
            raise ValueError("pf tracks one source; use multi-pf or mle for second_source")
        effects, params = tuple(self.effects), dict(self.effect_params or {})
        if self.dead_time_s:
            if params.setdefault("dead_time.tau_s", self.dead_time_s) != self.dead_time_s:
                raise ValueError(f"dead_time_s={self.dead_time_s} and effect_params dead_time.tau_s="
                                 f"{params['dead_time.tau_s']} are the same dead time: give one")
            effects = (*effects, "dead_time")
        self._model = MeasurementModel(scenario, effects=effects)
        known = set(self._model.param_names)
        bad = set(self.effect_params or {}) - known
        if self.effects and bad:
            raise ValueError(f"effect_params {sorted(bad)} not in the model's parameters {sorted(known)}")
        self._params = {k: v for k, v in params.items() if k in known}
        # without effects the particle rows go straight through expected_rate (no per-update Frames)
        self._direct = not self.effects

    @staticmethod
    def _frames(positions: np.ndarray, durations: np.ndarray, yaws: np.ndarray, ts: np.ndarray) -> Frames:
        """Measurements (pose, duration) as Frames for the MeasurementModel (counts are not used)."""
        k = len(positions)
        zeros = np.zeros(k)
        return Frames(t=ts, duration=durations, x=positions[:, 0], y=positions[:, 1], z=positions[:, 2], yaw=yaws,
                      var_x=zeros, var_y=zeros, var_z=zeros, dwell=np.full(k, -1),
                      counts=np.zeros((k, N_CHANNELS), dtype=np.int64))

    @property
    def particles_(self) -> np.ndarray:
        """(N, 4) particles: x, y, A (cps_at_1m), Bg (cps)."""
        return self.state_.T

    def _record(self, t: float) -> None:
        w = self.weights_
        mu, cov = weighted_mean_cov(self.state_[:2].T, w)
        self.history_.append({"t": float(t), "total_variance": total_variance_from_cov(cov),
                              "entropy": entropy_from_cov(cov), "mean": mu, "cov": cov,
                              "ess": float(1.0 / np.einsum("i,i->", w, w))})

    # --------------------------------------------------------------------------- update

    def expected_counts(self, position: np.ndarray, duration: float, yaw: float = 0.0, t: float = 0.0
                        ) -> np.ndarray:
        """(N,) expected counts of every particle for one measurement (eq. 9-10).

        With ``effects`` the composable :class:`estimator.model.MeasurementModel` computes them instead (effect
        parameters fixed at ``effect_params`` or the model defaults), vectorised over particles.
        """
        s = self.state_
        if not self._direct:
            one = self._frames(position[None, :], np.array([duration]), np.array([yaw]), np.array([t]))
            theta = {**self._params, **dict(zip(STATE_PARAMS, s, strict=True))}
            return self._model.expected_counts(theta, one)[:, 0]
        d2 = s[0] - position[0]
        d2 *= d2
        dy = s[1] - position[1]
        dy *= dy
        d2 += dy
        d2 += (self.scenario_.source_z - position[2]) ** 2
        lam = expected_rate(d2, s[2], s[3], self.dead_time_s)
        lam *= duration
        return lam

    def update(self, position: Any, counts: float, duration: float, t: float | None = None, yaw: float = 0.0
               ) -> ParticleFilter:
        """One measurement: ``counts`` (total) in ``duration`` s at detector ``position`` (x, y, z), heading
        ``yaw`` (used only by a model with anisotropy)."""
        if not hasattr(self, "particles_"):
            raise RuntimeError("call initialize(scenario) or fit() before update()")
        if self.converged_:
            return self
        pos = np.asarray(position, dtype=float)
        remaining = 1.0
        for _ in range(int(self.max_tempering_steps)):
            ll = self._loglik(pos, counts, duration, yaw, t)
            phi = self._temper_exponent(ll, remaining)
            self._apply(phi * ll)
            remaining -= phi
            if remaining <= 1e-12:
                break
            # adaptive tempering: the rest of this likelihood after a resample-and-roughen of the cloud
            self._resample()
        else:
            self._apply(remaining * self._loglik(pos, counts, duration, yaw, t))
        self.n_updates_ += 1
        self._meas.append((pos, float(duration), float(yaw), float(t if t is not None else 0.0)))
        w = self.weights_
        if 1.0 / np.einsum("i,i->", w, w) < self.resample_threshold * len(w):
            self._resample()
        self._record(t if t is not None else float(self.n_updates_))
        if self.stop_variance is not None and self.history_[-1]["total_variance"] < self.stop_variance:
            self.converged_ = True
        return self

    def _loglik(self, pos: np.ndarray, counts: float, duration: float, yaw: float, t: float | None) -> np.ndarray:
        mu = self.expected_counts(pos, duration, yaw, t if t is not None else 0.0)
        if self.likelihood == "poisson":
            return counts * np.log(mu) - mu
        var = self.gauss_const * mu
        return -0.5 * (counts - mu) ** 2 / var - 0.5 * np.log(var)

    def _ess(self, lw: np.ndarray) -> float:
        w = np.exp(lw - lw.max())
        s = w.sum()
        return float(s * s / np.einsum("i,i->", w, w))

    def _temper_exponent(self, ll: np.ndarray, remaining: float) -> float:
        """Largest phi <= remaining keeping ESS(w * L^phi) >= temper_ess * N (bisection on phi)."""
        target = self.temper_ess * len(ll)
        lw = self.log_weights_
        if self.max_tempering_steps <= 1 or self._ess(lw + remaining * ll) >= target:
            return remaining
        lo, hi = 0.0, remaining
        for _ in range(12):
            mid = 0.5 * (lo + hi)
            if self._ess(lw + mid * ll) >= target:
                lo = mid
            else:
                hi = mid
        return max(lo, remaining / 64)

    def _apply(self, ll: np.ndarray) -> None:
        lw = self.log_weights_
        lw += ll
        lw -= lw.max()
        w = np.exp(lw)
        w /= w.sum()
        self.weights_ = w

    def _resample(self) -> None:
        rng = self.rng_
        idx = low_variance_resample(self.weights_, rng)
        s = np.take(self.state_, idx, axis=1)
        n = s.shape[1]
        if self.roughening:
            sd = self.roughening * np.ptp(s, axis=1) * n ** (-1 / 4)
            s += rng.standard_normal(s.shape, dtype=np.float32) * sd.astype(np.float32)[:, None]
            lo, hi = self.scenario_.bounds_min, self.scenario_.bounds_max
            np.clip(s[0], lo[0], hi[0], out=s[0])
            np.clip(s[1], lo[1], hi[1], out=s[1])
            np.abs(s[2:], out=s[2:])
        self.state_ = s
        self.log_weights_ = np.zeros(n)
        self.weights_ = np.full(n, 1.0 / n)
        self.n_resamples_ += 1

    # -------------------------------------------------------------------------- fitting

    def _feed(self, frames: Frames) -> None:
        pos = frames.positions
        tot = frames.total_counts
        for g in chunk_frames(frames, self.chunk_s):
            yaw = float(np.arctan2(np.sin(frames.yaw[g]).mean(), np.cos(frames.yaw[g]).mean()))
            self.update(pos[g].mean(axis=0), float(tot[g].sum()), float(frames.duration[g].sum()),
                        t=float(frames.t[g[-1]]), yaw=yaw)
        self._summarize()

    def _fit(self, frames: Frames, scenario: Scenario) -> None:
        self.initialize(scenario)
        self._feed(frames)

    def _partial_fit(self, frames: Frames, scenario: Scenario) -> None:
        self._feed(frames)

    def _summarize(self) -> None:
        mu, cov = weighted_mean_cov(self.particles_, self.weights_)
        z = self.scenario_.source_z
        self.sources_ = [source_dict(mu[0], mu[1], z, mu[2])]
        c = np.zeros((4, 4))
        sel = [0, 1, 3]  # (x, y, A) into (x, y, z, A)
        c[np.ix_(sel, sel)] = cov[np.ix_([0, 1, 2], [0, 1, 2])]
        c[2, 2] = 1e-9
        self.covariance_ = c
        self.background_ = float(mu[3])
        self.background_std_ = float(math.sqrt(max(cov[3, 3], 0.0)))
        self.crlb_ = None
        if self._meas:
            pos, dur, yaw, t = zip(*self._meas, strict=True)
            frames = self._frames(np.array(pos), np.array(dur), np.array(yaw), np.array(t))
            theta = {**self._params, **dict(zip(STATE_PARAMS, mu, strict=True))}
            j = crlb(self._model, theta, frames, STATE_PARAMS)
            cr = np.zeros((4, 4))
            cr[np.ix_(sel, sel)] = j[np.ix_([0, 1, 2], [0, 1, 2])]
            self.crlb_ = cr
        h = self.history_[-1]
        self.info_ = {"n_updates": self.n_updates_, "n_resamples": self.n_resamples_, "converged": self.converged_,
                      "total_variance": h["total_variance"], "entropy": h["entropy"], "ess": h["ess"]}
