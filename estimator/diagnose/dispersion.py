"""Over-dispersion: extra-Poisson variance of the frame counts, tested so that a wrong *mean* cannot fake it.

Effect ``over_dispersion`` (parameter ``rel_sd``): the rate of each frame fluctuates independently by a factor
with relative standard deviation r (a gamma factor: the counts are negative binomial, Var = mu + r^2 mu^2).
Real detectors show it (electronic noise bursts, vibration of the mount, an unsteady high voltage), and an
unmodelled mean structure (a missing wall, a wrong source) looks exactly like it frame by frame. To tell the
two apart the test conditions on pairs of consecutive frames of the same dwell / transit segment: given their
sum s, the first frame's count is Binomial(s, p) with p = mu_1 / (mu_1 + mu_2) when the counts are Poisson, and
Beta-binomial(s, 2 p / r^2, 2 (1 - p) / r^2) when each frame has its own gamma factor. A mean misfit that is
smooth over 0.2 s (every geometry effect: walls, distance, bearing, pose errors) multiplies both frames alike
and cancels from p, so it cannot be called over-dispersion, and over-dispersion cannot be called geometry:
when it is in the model the count model's likelihood-ratio statistics are divided by the dispersion factor
phi = 1 + r^2 sum(mu^2) / sum(mu) (quasi-likelihood).

The likelihood-ratio statistic for r > 0 has its parameter on the boundary: null 1/2 chi2_0 + 1/2 chi2_1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize
from scipy.special import betaln

from radseek.dataset import Frames

MAX_R2 = 1.0


@dataclass
class DispersionFit:
    rel_sd: float  # r
    error: float  # 1-sigma of r (nan at the boundary)
    lr: float  # 2 (ll(r_hat) - ll(0)) on the pair likelihood
    n_pairs: int
    phi: float  # count-weighted variance inflation 1 + r^2 sum(mu^2) / sum(mu) at the fitted means

    def to_json(self) -> dict[str, float]:
        return {"rel_sd": self.rel_sd, "error": self.error, "lr": self.lr, "n_pairs": self.n_pairs, "phi": self.phi}


def frame_pairs(frames: Frames, labels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Indices (i, j = i + 1) of disjoint pairs of consecutive frames in the same segment (dwell or transit run)."""
    dw = np.asarray(frames.dwell) if labels is None else np.asarray(labels)
    n = len(dw)
    i = np.arange(0, n - 1)
    same = dw[i] == dw[i + 1]
    # disjoint: within each run take frames 0-1, 2-3, ...
    start = np.r_[True, dw[1:] != dw[:-1]]
    run_first = np.maximum.accumulate(np.where(start, np.arange(n), 0))
    even = ((i - run_first[i]) % 2) == 0
    ok = same & even
    return i[ok], i[ok] + 1


def _ll_pairs(x: np.ndarray, s: np.ndarray, p: np.ndarray, r2: float) -> float:
    if r2 <= 0:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(x > 0, x * np.log(p), 0.0) + np.where(s - x > 0, (s - x) * np.log1p(-p), 0.0)
        return float(t.sum())
    a, b = 2 * p / r2, 2 * (1 - p) / r2
    return float((betaln(x + a, s - x + b) - betaln(a, b)).sum())


def fit_dispersion(frames: Frames, expected: np.ndarray, counts: np.ndarray | None = None) -> DispersionFit:
    """Fit r on consecutive-frame pairs given the model's expected counts per frame (see the module docstring)."""
    n = frames.total_counts.astype(float) if counts is None else np.asarray(counts, dtype=float)
    mu = np.maximum(np.asarray(expected, dtype=float), 1e-9)
    i, j = frame_pairs(frames)
    s = n[i] + n[j]
    keep = s > 0
    i, j, s = i[keep], j[keep], s[keep]
    x = n[i]
    p = np.clip(mu[i] / (mu[i] + mu[j]), 1e-9, 1 - 1e-9)
    ll0 = _ll_pairs(x, s, p, 0.0)
    if len(s) < 10:
        return DispersionFit(0.0, float("nan"), 0.0, int(len(s)), 1.0)

    def neg(lr2: float) -> float:
        return -_ll_pairs(x, s, p, float(np.exp(lr2)))

    res = optimize.minimize_scalar(neg, bounds=(np.log(1e-7), np.log(MAX_R2)), method="bounded",
                                   options={"xatol": 1e-3})
    r2 = float(np.exp(res.x))
    ll1 = -float(res.fun)
    if ll1 <= ll0:
        r2, ll1 = 0.0, ll0
    lr = max(2 * (ll1 - ll0), 0.0)
    err = float("nan")
    if r2 > 0:
        h = max(r2 * 0.05, 1e-8)
        f = [_ll_pairs(x, s, p, v) for v in (max(r2 - h, 1e-12), r2, r2 + h)]
        curv = -(f[0] - 2 * f[1] + f[2]) / h**2
        if curv > 0:
            err = float(1 / np.sqrt(curv) / (2 * np.sqrt(r2)))  # delta method: sd(r) = sd(r^2) / (2 r)
    phi = 1.0 + r2 * float((mu**2).sum() / mu.sum())
    return DispersionFit(float(np.sqrt(r2)), err, lr, int(len(s)), phi)
