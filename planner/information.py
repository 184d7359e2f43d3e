"""Information planner: score candidate dwell points by the expected D-optimal reduction of the source's
x-y posterior covariance, under the pose drift their paths add, and choose each dwell's length by
information per second.

The count model is the one every localizer uses (``radseek.count_model.expected_rate`` through
``SourceBelief.predicted_net_rate``): a dwell of T s at p records n ~ Poisson(T lambda(p; theta)),
theta = (x_s, y_s, S, B) (the source height is the operator's ``source_z``). Its Poisson Fisher information
(paper 004 eq. 5.3, as ``estimator.mle.fisher_information``) is T g g^T / lambda, g = d lambda / d theta.

Pose drift (the drift-aware bound's random walk, ``estimator.localizers.mle.pose_aware_crlb``): the dwell is
measured from a pose off by e ~ N(0, Sigma_p), Sigma_p the pose variance there (the recorded variance of a
flown dwell; for a candidate the variance now plus ``drift_density`` x the path length to it). Taking e as a
nuisance with that prior (the hybrid bound's Schur complement, here for one rank-one measurement) leaves

    J = g g^T / (lambda / T + g_d^T Sigma_p g_d),   g_d = d lambda / d p = -d lambda / d p_s,

so near the source, where g_d is large, drift caps what a longer dwell can add. The flown information is
that sum over the flown dwells (frames of a dwell pooled: one pose error for the whole hover) and the
transit frames, plus a weak prior; its inverse C is the current covariance of theta. A candidate adds a
rank-one term c g g^T; the D-optimal gain on the x-y marginal is

    Delta = -log det(C'_xy) + log det(C_xy) = -log(1 - c u^T C_xy^-1 u / (1 + c g^T C g)),  u = (C g)_xy,

in nats. Each (node, T) for T in ``dwell_lengths_s`` is scored by Delta per second of the leg (flight at
the tree's speed, a fixed settling overhead, the dwell); the best pair is the next dwell and its length.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from planner.belief import SourceBelief
from radseek.dataset import Frames, Wall

#: m, central-difference step of the source-position derivatives
_H = 1e-3


@dataclass(frozen=True)
class InfoConfig:
    """Settings of the information planner."""

    dwell_lengths_s: tuple[float, ...] = (5.0, 10.0, 15.0)  # s of dwell clock: the lengths compared per node
    overhead_s: float = 3.0  # s per leg beside flight and dwell: accelerating, settling at the point
    speed_m_s: float = 1.0  # m/s, the leg speed the flight time is charged at
    prior_sd_m: float = 10.0  # m, weak prior on the source's x, y (keeps C finite before the counts pin it)

    def __post_init__(self) -> None:
        if not self.dwell_lengths_s or min(self.dwell_lengths_s) <= 0:
            raise ValueError("dwell_lengths_s must be a non-empty tuple of lengths > 0")
        if self.overhead_s < 0 or self.speed_m_s <= 0 or self.prior_sd_m <= 0:
            raise ValueError("need overhead_s >= 0, speed_m_s > 0 and prior_sd_m > 0")


def rate_and_gradient(points: np.ndarray, belief: SourceBelief, walls: Sequence[Wall] = (),
                      wall_mu_per_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Gross rate lambda (N,) cps at points (N, 3) and its gradient (N, 4) over theta = (x_s, y_s, S, B), from
    the belief's mean, strength and background (``SourceBelief.predicted_net_rate``: the shared count model)."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    net = belief.predicted_net_rate(pts, walls, wall_mu_per_m)
    grad = np.empty((len(pts), 4))
    for k in range(2):
        step = np.zeros(3)
        step[k] = _H
        hi = SourceBelief(belief.mean + step, belief.covariance, belief.cps_at_1m)
        lo = SourceBelief(belief.mean - step, belief.covariance, belief.cps_at_1m)
        grad[:, k] = (hi.predicted_net_rate(pts, walls, wall_mu_per_m)
                      - lo.predicted_net_rate(pts, walls, wall_mu_per_m)) / (2 * _H)
    grad[:, 2] = net / belief.cps_at_1m
    grad[:, 3] = 1.0
    return net + belief.background_cps, grad


def measurement_weight(rate: np.ndarray, grad: np.ndarray, dwell_s: np.ndarray | float,
                       pose_var: np.ndarray) -> np.ndarray:
    """c of J = c g g^T: 1 / (lambda / T + g_d^T Sigma_p g_d) for measurements (N,) with diagonal pose
    variances (N, 3) (only x, y enter: the model's source height is fixed, and d lambda / d p = -g_xy)."""
    var = np.asarray(pose_var, dtype=float).reshape(-1, 3)
    drift = (grad[:, :2] ** 2 * var[:, :2]).sum(-1)
    return 1.0 / (np.asarray(rate) / np.asarray(dwell_s, dtype=float) + drift)


def flown_information(frames: Frames | None, belief: SourceBelief, walls: Sequence[Wall] = (),
                      wall_mu_per_m: float = 0.0, prior_sd_m: float = 10.0) -> np.ndarray:
    """Fisher information (4, 4) over theta of the flown frames under their pose variances: each dwell pooled
    into one measurement at its mean pose (one pose error for the hover), each transit frame on its own; plus
    a weak prior (``prior_sd_m`` on x_s, y_s; 100 % on S; the background's Poisson sd over 1 s)."""
    prior = np.diag([prior_sd_m**-2, prior_sd_m**-2, belief.cps_at_1m**-2, 1.0 / max(belief.background_cps, 1.0)])
    n = 0 if frames is None else len(frames.t)
    if n == 0:
        return prior
    pos = np.column_stack([frames.x, frames.y, frames.z]).astype(float)
    var = np.column_stack([frames.var_x, frames.var_y, frames.var_z]).astype(float)
    var = np.where(np.isfinite(var), var, 0.0)
    dur = np.asarray(frames.duration, dtype=float)
    dwell = np.asarray(frames.dwell)
    groups = np.where(dwell >= 0, dwell, -1 - np.arange(n))  # transit frames: a group each
    keys, inv = np.unique(groups, return_inverse=True)
    t_sum = np.bincount(inv, weights=dur, minlength=len(keys))
    w = dur / np.maximum(t_sum[inv], 1e-12)
    g_pos = np.column_stack([np.bincount(inv, weights=w * pos[:, k], minlength=len(keys)) for k in range(3)])
    g_var = np.column_stack([np.bincount(inv, weights=w * var[:, k], minlength=len(keys)) for k in range(3)])
    rate, grad = rate_and_gradient(g_pos, belief, walls, wall_mu_per_m)
    c = measurement_weight(rate, grad, t_sum, g_var)
    return prior + (grad * c[:, None]).T @ grad


def xy_gain(cov: np.ndarray, grad: np.ndarray, c: np.ndarray) -> np.ndarray:
    """D-optimal gain (nats) on the x-y marginal of adding c g g^T to the information whose inverse is ``cov``
    (4, 4), for rows grad (N, 4) and weights c (N,) or (N, L) -> same shape as c."""
    v = grad @ cov  # (N, 4) = (C g)^T
    q = (v * grad).sum(-1)  # g^T C g
    cxy_inv = np.linalg.inv(cov[:2, :2])
    s = np.einsum("ni,ij,nj->n", v[:, :2], cxy_inv, v[:, :2])  # u^T C_xy^-1 u
    c = np.asarray(c, dtype=float)
    shape = (-1,) + (1,) * (c.ndim - 1)
    ratio = c * s.reshape(shape) / (1.0 + c * q.reshape(shape))
    return -np.log(np.clip(1.0 - ratio, 1e-300, 1.0))


@dataclass(frozen=True)
class InfoScores:
    """Per node: the best information rate (nats/s), its gain (nats) and dwell length (s)."""

    rate: np.ndarray
    gain: np.ndarray
    dwell_s: np.ndarray


def score_information(positions: np.ndarray, path_length: np.ndarray, belief: SourceBelief, frames: Frames | None,
                      pose_var_now: np.ndarray, config: InfoConfig = InfoConfig(), walls: Sequence[Wall] = (),
                      wall_mu_per_m: float = 0.0) -> InfoScores:
    """Score candidate nodes (N, 3) reached after ``path_length`` (N,) m from a pose of variance
    ``pose_var_now`` (3,) after ``frames`` (None: nothing flown): the expected x-y D-optimal gain per second
    of each dwell length, the best kept."""
    pos = np.asarray(positions, dtype=float).reshape(-1, 3)
    length = np.maximum(np.asarray(path_length, dtype=float).reshape(-1), 0.0)
    cov = np.linalg.inv(flown_information(frames, belief, walls, wall_mu_per_m, config.prior_sd_m))
    cov = 0.5 * (cov + cov.T)
    rate, grad = rate_and_gradient(pos, belief, walls, wall_mu_per_m)
    var = np.asarray(pose_var_now, dtype=float).reshape(1, 3) + length[:, None] * belief.drift_density
    lengths = np.asarray(config.dwell_lengths_s, dtype=float)
    c = np.column_stack([measurement_weight(rate, grad, t, var) for t in lengths])  # (N, L)
    gain = xy_gain(cov, grad, c)
    per_s = gain / (length[:, None] / config.speed_m_s + config.overhead_s + lengths[None, :])
    best = np.argmax(per_s, axis=1)
    idx = np.arange(len(pos))
    return InfoScores(rate=per_s[idx, best], gain=gain[idx, best], dwell_s=lengths[best])
