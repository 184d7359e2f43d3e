"""The planner's view of the source: a Gaussian position belief plus strength and background.

The planner never sees the estimator's internals nor the simulator's truth: it takes this small
record (filled by the mission layer from ``radseek.topics.Estimate``) and plain arrays.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from radseek import topics
from radseek.count_model import expected_rate
from radseek.dataset import Wall
from radseek.estimate import SourceEstimate
from radseek.geometry import path_lengths, semi_major_axis


@dataclass(frozen=True)
class SourceBelief:
    """Source estimate [p_s, Sigma_s, lambda_s] of paper 003 sec. IV-B-3.

    mean: (3,) m, ENU; covariance: (3, 3) m^2 (symmetric positive semi-definite);
    cps_at_1m: net count rate at 1 m (cps, > 0); background_cps: >= 0;
    drift_density: (3,) m^2 per metre flown, >= 0: the odometry's pose variance growth per axis (a random
    walk in distance flown; :func:`drift_density_from_poses`), used by the pose-covariance gain. A scalar
    means the same density on every axis; 0 (default) treats the pose as exact.
    """

    mean: np.ndarray
    covariance: np.ndarray
    cps_at_1m: float
    background_cps: float = 0.0
    drift_density: np.ndarray | float = 0.0

    def __post_init__(self) -> None:
        mean = np.asarray(self.mean, dtype=float).reshape(3)
        cov = np.asarray(self.covariance, dtype=float).reshape(3, 3)
        if not np.allclose(cov, cov.T):
            raise ValueError("covariance must be symmetric")
        if np.linalg.eigvalsh(cov).min() < -1e-12:
            raise ValueError("covariance must be positive semi-definite")
        if not self.cps_at_1m > 0 or self.background_cps < 0:
            raise ValueError("need cps_at_1m > 0 and background_cps >= 0")
        dens = np.broadcast_to(np.asarray(self.drift_density, dtype=float), (3,)).copy()
        if not (np.isfinite(dens).all() and (dens >= 0).all()):
            raise ValueError("drift_density must be finite and >= 0")
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "covariance", cov)
        object.__setattr__(self, "drift_density", dens)

    @classmethod
    def from_estimate(cls, msg: topics.Estimate, source: int = 0) -> SourceBelief:
        """The belief of one source of an ``estimate`` message: its position block of
        ``msg.covariance_block(source)`` (the layout ``radseek.topics.Estimate`` declares). A message
        that breaks the layout raises ``topics.PayloadError``."""
        est = SourceEstimate.from_topic(msg, source)  # the one reader of the topic's layout
        return cls(est.position, est.covariance, est.cps_at_1m, est.background_cps)

    def semi_major_axis(self, extra_covariance: np.ndarray | None = None) -> float:
        """Largest semi-axis (m) of the 1-sigma ellipsoid of covariance (+ extra, e.g. the pose's): the
        planner's geometric size of the belief (3-D); the estimate's 1-sigma is ``estimator.inflight.sigma_m``."""
        cov = self.covariance if extra_covariance is None else self.covariance + np.asarray(extra_covariance)
        return semi_major_axis(cov)

    def predicted_net_rate(self, points: np.ndarray, walls: Sequence[Wall] = (), wall_mu_per_m: float = 0.0
                           ) -> np.ndarray:
        """Net (background-free) rate (cps) at points (..., 3) from the mean source: paper 003 eq. 1-4,
        lambda = cps_at_1m / r^2 * exp(-mu * wall path length) (:func:`radseek.count_model.expected_rate`)."""
        p = np.asarray(points, dtype=float)
        attenuation = None
        if walls and wall_mu_per_m > 0:
            attenuation = np.exp(-wall_mu_per_m * path_lengths(p, self.mean, walls))
        return expected_rate(((p - self.mean) ** 2).sum(-1), self.cps_at_1m, attenuation=attenuation)


def drift_density_from_poses(positions: np.ndarray, variances: np.ndarray, dwell: np.ndarray | None = None
                             ) -> np.ndarray:
    """(3,) m^2/m: how fast the reported pose variance grows per metre flown, from recorded estimated
    positions (n, 3) and their variances (n, 3) (the frames' x, y, z and var_x, var_y, var_z).

    Odometry drift is a random walk in distance flown (``vehicle_sim.odometry``), so its variance grows
    linearly with the path: density = (var_last - var_first) / path length. ``dwell`` (n,) (the frames'
    dwell index, -1 in transit): steps between frames of the same dwell are hover jitter, not flight, and
    are not counted. Zero when nothing was flown, the variance did not grow, or the columns are not finite.
    """
    pos = np.asarray(positions, dtype=float).reshape(-1, 3)
    var = np.asarray(variances, dtype=float).reshape(-1, 3)
    if len(pos) < 2 or len(var) != len(pos) or not (np.isfinite(pos).all() and np.isfinite(var).all()):
        return np.zeros(3)
    step = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    if dwell is not None and len(dwell) == len(pos):
        d = np.asarray(dwell)
        step = np.where((d[1:] == d[:-1]) & (d[1:] >= 0), 0.0, step)
    flown = float(step.sum())
    if flown <= 1e-6:
        return np.zeros(3)
    return np.clip((var[-1] - var[0]) / flown, 0.0, None)


@dataclass(frozen=True)
class DwellHistory:
    """Previous dwell points p_k (K, 3) and their gross mean rates lambda_k (K,) in cps."""

    positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    rates: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        pos = np.asarray(self.positions, dtype=float).reshape(-1, 3)
        rates = np.asarray(self.rates, dtype=float).reshape(-1)
        if len(rates) != len(pos):
            raise ValueError("positions and rates must have the same length")
        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "rates", rates)

    def __len__(self) -> int:
        return len(self.rates)

    def above_background(self, background_cps: float, k_sigma: float = 3.0, dwell_s: float = 5.0) -> np.ndarray:
        """Mask of readings significantly above background: lambda_k - b > k sqrt(b / T) (Poisson)."""
        return self.rates - background_cps > k_sigma * np.sqrt(max(background_cps, 1e-9) / dwell_s)
