"""Residuals of a Poisson count model: per frame, per dwell/segment, binned against a feature.

- Pearson residual (n - mu) / sqrt(mu); deviance residual sign(n - mu) sqrt(2 (n log(n/mu) - (n - mu))).
- At 10 Hz a background frame holds ~3 counts, where the Poisson deviance of a frame has mean 1 + 1/(6 mu) + ...
  rather than 1, so the goodness of fit uses the exact mean and variance of each frame's deviance
  (``deviance_moments``), not the chi-square approximation.
- A *trend* bins frames by a feature (quantiles), sums observed and expected counts per bin and tests the
  bin residuals (chi-square over bins) and their slope: "residuals fall with count rate".
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import stats
from scipy.special import gammaln

from radseek.dataset import Frames


def pearson(n: np.ndarray, mu: np.ndarray) -> np.ndarray:
    mu = np.maximum(np.asarray(mu, dtype=float), 1e-12)
    return (np.asarray(n, dtype=float) - mu) / np.sqrt(mu)


def unit_deviance(n: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """2 (n log(n/mu) - (n - mu)) elementwise, with 0 log 0 = 0."""
    n = np.asarray(n, dtype=float)
    mu = np.maximum(np.asarray(mu, dtype=float), 1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        term = np.where(n > 0, n * np.log(n / mu), 0.0)
    return 2.0 * (term - (n - mu))


def deviance_residuals(n: np.ndarray, mu: np.ndarray) -> np.ndarray:
    return np.sign(np.asarray(n, dtype=float) - mu) * np.sqrt(np.maximum(unit_deviance(n, mu), 0.0))


@lru_cache(maxsize=1)
def _moment_table() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    grid = np.geomspace(1e-3, 2e3, 240)
    nmax = int(grid[-1] + 14 * np.sqrt(grid[-1]) + 40)
    n = np.arange(nmax + 1, dtype=float)[None, :]
    mu = grid[:, None]
    logp = n * np.log(mu) - mu - gammaln(n + 1)
    p = np.exp(logp)
    d = unit_deviance(n, mu)
    mean = (p * d).sum(1)
    var = (p * d**2).sum(1) - mean**2
    return grid, mean, var


def deviance_moments(mu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact mean and variance of one Poisson observation's unit deviance at mean ``mu`` (elementwise)."""
    grid, mean, var = _moment_table()
    mu = np.asarray(mu, dtype=float)
    lm = np.log(np.clip(mu, grid[0], grid[-1]))
    m = np.interp(lm, np.log(grid), mean)
    v = np.interp(lm, np.log(grid), var)
    big = mu > grid[-1]
    m = np.where(big, 1.0 + 1.0 / (6.0 * np.maximum(mu, 1e-12)), m)
    v = np.where(big, 2.0, v)
    return m, v


def pose_penalty(fit: object, n: np.ndarray, mu: np.ndarray) -> float:
    """The pose offsets' Gaussian penalty inside a fit's deviance (``estimator.mle.FitResult.deviance``), kept in
    the goodness of fit so that E[deviance] ~ N - k still holds; 0 for a fit without one."""
    if not hasattr(fit, "deviance"):
        return 0.0
    return max(float(fit.deviance) - float(unit_deviance(n, mu).sum()), 0.0)


@dataclass(frozen=True)
class GoodnessOfFit:
    deviance: float
    dof: int
    deviance_per_dof: float
    expected_per_dof: float  # mean of deviance/dof if the model were right (low-count corrected)
    sd_per_dof: float  # its standard deviation
    p_value: float  # one-sided, normal approximation with the exact moments


def goodness_of_fit(n: np.ndarray, mu: np.ndarray, n_params: int, penalty: float = 0.0,
                    rel_var: float = 0.0) -> GoodnessOfFit:
    """Deviance (plus ``penalty``: the pose offsets' sum delta^T Sigma^-1 delta, which makes a fit with
    Gaussian random offsets comparable to one without: its expectation is still about N - k).

    ``rel_var`` = r^2 of an over-dispersed model (Var = mu + r^2 mu^2): the Poisson deviance of a frame then
    has mean ~ (its Poisson mean) + r^2 mu and its variance grows by (1 + r^2 mu)^2 (to first order)."""
    d = float(unit_deviance(n, mu).sum()) + max(float(penalty), 0.0)
    m, v = deviance_moments(mu)
    if rel_var > 0:
        mu_ = np.asarray(mu, dtype=float)
        m = m + rel_var * mu_
        v = v * (1 + rel_var * mu_) ** 2
    dof = max(len(np.atleast_1d(n)) - n_params, 1)
    expected = float(m.sum()) - n_params
    sd = float(np.sqrt(v.sum()))
    p = float(stats.norm.sf((d - expected) / sd)) if sd > 0 else float("nan")
    return GoodnessOfFit(d, dof, d / dof, expected / dof, sd / dof, p)


def segments(frames: Frames, transit_s: float = 1.0, dwell_s: float = 1e9) -> np.ndarray:
    """Label frames: each dwell is one segment (split every ``dwell_s``), transit runs split every ``transit_s``."""
    n = len(frames)
    labels = np.empty(n, dtype=int)
    cur = -1
    start_t = -np.inf
    prev = None
    for i in range(n):  # O(N) bookkeeping only, no arithmetic on counts
        dw = int(frames.dwell[i])
        limit = dwell_s if dw >= 0 else transit_s
        if dw != prev or frames.t[i] - start_t >= limit:
            cur += 1
            start_t = frames.t[i] - frames.duration[i]
            prev = dw
        labels[i] = cur
    return labels


def aggregate(labels: np.ndarray, *arrays: np.ndarray) -> list[np.ndarray]:
    """Sum each (N,) or (N, k) array over ``labels`` (0..G-1)."""
    g = int(labels.max()) + 1 if len(labels) else 0
    out = []
    for a in arrays:
        a = np.asarray(a, dtype=float)
        shape = (g,) + a.shape[1:]
        acc = np.zeros(shape)
        np.add.at(acc, labels, a)
        out.append(acc)
    return out


def group_mean(labels: np.ndarray, values: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    w = np.ones(len(values)) if weights is None else np.asarray(weights, dtype=float)
    s, sw = aggregate(labels, values * w, w)
    return s / np.where(sw > 0, sw, 1.0)


@dataclass(frozen=True)
class Trend:
    """Residuals binned against one feature."""

    feature: str
    centres: np.ndarray  # (B,) mean feature value per bin
    observed: np.ndarray  # (B,) counts
    expected: np.ndarray  # (B,) counts
    chi2: float
    dof: int
    p_value: float
    slope_z: float  # z-score of the linear trend of the relative residual across the bins (by rank)
    #: indices i of bins followed by empty bins (no frames between bin i and bin i + 1): a plot breaks its line there
    gaps_after: tuple[int, ...] = ()

    @property
    def rel(self) -> np.ndarray:
        return self.observed / np.maximum(self.expected, 1e-12) - 1.0

    @property
    def rel_err(self) -> np.ndarray:
        return 1.0 / np.sqrt(np.maximum(self.expected, 1e-12))

    @property
    def log10_p(self) -> float:
        return float(stats.chi2.logsf(self.chi2, self.dof) / np.log(10)) if self.dof > 0 else 0.0


def trend(name: str, feature: np.ndarray, n: np.ndarray, mu: np.ndarray, n_bins: int = 8, log: bool = False,
          zero_bin: bool = False) -> Trend | None:
    """Bin frames into quantiles of ``feature`` (or equal steps of its log, for scale-like features such as
    rate and distance, so the few high-rate frames get bins of their own) and test observed vs expected.
    ``zero_bin``: exact zeros get a bin of their own and the positive values share the others (wall paths)."""
    feature = np.asarray(feature, dtype=float)
    if zero_bin and np.any(feature > 0) and np.any(feature <= 0):
        pos = feature[feature > 0]
        inner = np.unique(np.quantile(pos, np.linspace(0, 1, n_bins)))
        qs = np.unique(np.r_[0.0, inner[0] * (1 - 1e-9), inner[1:]])
    elif log and np.all(feature > 0):
        lf = np.log(feature)
        qs = np.unique(np.exp(np.linspace(lf.min(), lf.max(), n_bins + 1)))
    else:
        qs = np.unique(np.quantile(feature, np.linspace(0, 1, n_bins + 1)))
    if len(qs) < 3:
        return None
    idx = np.clip(np.searchsorted(qs, feature, side="right") - 1, 0, len(qs) - 2)
    b = len(qs) - 1
    obs = np.bincount(idx, weights=np.asarray(n, float), minlength=b)
    exp = np.bincount(idx, weights=np.asarray(mu, float), minlength=b)
    cnt = np.bincount(idx, minlength=b)
    keep = (cnt > 0) & (exp > 0)
    if keep.sum() < 2:
        return None
    centres = np.bincount(idx, weights=feature, minlength=b)[keep] / cnt[keep]
    obs, exp = obs[keep], exp[keep]
    z = (obs - exp) / np.sqrt(exp)
    chi2 = float((z**2).sum())
    dof = int(keep.sum()) - 1  # the fit fixes the overall level
    # weighted least squares slope of the relative residual on the bin rank
    r = obs / exp - 1.0
    w = exp
    x = np.arange(len(r), dtype=float)
    xm = (w * x).sum() / w.sum()
    sxx = (w * (x - xm) ** 2).sum()
    slope = (w * (x - xm) * r).sum() / sxx if sxx > 0 else 0.0
    slope_z = float(slope * np.sqrt(sxx))
    gaps = tuple(int(i) for i in np.flatnonzero(np.diff(np.flatnonzero(keep)) > 1))
    return Trend(name, centres, obs, exp, chi2, dof, float(stats.chi2.sf(chi2, dof)), slope_z, gaps)


def broken_at_gaps(t: Trend, *series: np.ndarray) -> list[np.ndarray]:
    """Each of ``series`` (one value per bin of ``t``) with NaN inserted after every bin followed by empty bins,
    so a plotted line breaks where there is no data instead of joining across it."""
    at = np.asarray(t.gaps_after, dtype=int) + 1
    return [np.insert(np.asarray(v, dtype=float), at, np.nan) for v in series]


def describe_trend(t: Trend, unit: str = "", alpha: float = 0.01) -> str:
    """One line: does the residual follow this feature, and how?"""
    if t.p_value >= alpha:
        return f"no significant trend with {t.feature} (chi2 {t.chi2:.1f}/{t.dof})"
    rel = t.rel
    if abs(t.slope_z) >= 3.0 and t.slope_z ** 2 > 0.5 * t.chi2:
        way = "rise" if t.slope_z > 0 else "fall"
        lo, hi = t.centres[0], t.centres[-1]
        return (f"residuals {way} with {t.feature} ({rel[0]:+.1%} at {lo:.3g} {unit} -> {rel[-1]:+.1%} at "
                f"{hi:.3g} {unit}; chi2 {t.chi2:.1f}/{t.dof})").replace("  ", " ")
    k = int(np.argmax(np.abs(rel) / t.rel_err))
    kind = "excess" if rel[k] > 0 else "deficit"
    return (f"residuals vary with {t.feature}: {kind} of {rel[k]:+.1%} near {t.centres[k]:.3g} {unit} "
            f"(chi2 {t.chi2:.1f}/{t.dof})").replace("  ", " ")
