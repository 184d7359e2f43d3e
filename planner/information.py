"""Information planner: score candidate dwell points by the expected D-optimal reduction of the source's
x-y posterior covariance, under the pose drift their paths add, and choose each dwell's length by
information per second.

The count model is the one every localizer uses (``radseek.count_model.expected_rate`` through
``SourceBelief.predicted_net_rate``): a dwell of T s at p records n ~ Poisson(T lambda(p; theta)),
theta = (x_s, y_s, S, B) (the source height is the operator's ``source_z``). Its Poisson Fisher information
(paper 004 eq. 5.3, as ``estimator.mle.fisher_information``) is T g g^T / lambda, g = d lambda / d theta.

Pose drift (the drift-aware bound's random walk, ``estimator.localizers.mle.pose_aware_crlb``): the
odometry's pose error e(s) is one random walk in distance flown s, so the errors of two dwells are correlated,
Cov(e_i, e_j) = Var(e(min(s_i, s_j))): a shared offset plus the drift flown between them. With
``InfoConfig.drift = "random_walk"`` (default) the flown frames are cut into pose groups as the estimator cuts
them (a dwell; transit runs of ``TRANSIT_CHUNK`` frames), each group's x-y offset a nuisance under that
prior (increments = the growth of the recorded variance), and the hybrid information over (theta, e_1..e_G)

    H = [[J_tt + P_0, J_te], [J_et, J_ee + Lambda]],   Lambda the walk's (block-tridiagonal) precision,

is inverted for the joint covariance P of (theta, e_last), the Schur complement of every other offset. A
candidate reached after L m is measured at e_new = e_last + w, w ~ N(0, a), a = (pose variance now - the
last group's) + ``drift_density`` x L, with the count derivative h = (g, -g_xy) over (theta, e_new)
(d lambda / d e = -d lambda / d p_s: an offset moves the measured world with the vehicle). Its rank-one
update of P' = P + diag(0, a) gives the x-y D-optimal gain

    Delta = -log(1 - c u^T C_xy^-1 u / (1 + c h^T P' h)),   c = T / lambda,  u = (P' h)_xy,  C_xy = P_xy,

in nats. So a candidate whose drift from the flown dwells is small, and whose geometry separates the source
from the shared offset, is worth more than the same point scored with an independent pose error.

Mapped walls are landmarks (``InfoConfig.landmarks``, default): the offset moves the detector alone, the walls
stay where the map has them, so d lambda / d e is the rate's gradient in the detector's position
(:func:`offset_gradient`, ``pose_aware_crlb(landmarks=True)``), not -g_xy. Without walls the two are the same
(the inverse square depends on p - p_s only). At a wall's shadow edge the rate moves with the detector's pose
but hardly with the source's, so such a dwell tells the drift and the score values it; with
``landmarks=False`` an offset moves the walls too and the edge only costs counts (lattice-wall, traced: the
lattice's third dwell, behind the wall's corner after 5 m of flight, takes the landmark bound from 0.38 to
0.056 m while the landmark-free one stays at 0.12 m; the information planner's flights never went there).

``drift = "independent"`` (the first version, kept as a baseline): each measurement's pose error is its own,
e ~ N(0, Sigma_p), which leaves the rank-one information

    J = g g^T / (lambda / T + g_d^T Sigma_p g_d),   g_d = d lambda / d p = -d lambda / d p_s;

the flown information sums that over the flown dwells (frames of a dwell pooled) and transit frames, plus a
weak prior; its inverse C is the covariance of theta, and a candidate (Sigma_p = the variance now +
``drift_density`` x L) adds c g g^T, Delta = -log(1 - c u^T C_xy^-1 u / (1 + c g^T C g)), u = (C g)_xy.
Without flown frames, or with exact recorded poses, the two agree.

Each (node, T) for T in ``dwell_lengths_s`` is scored by Delta per second of the leg (flight at the tree's
speed, a fixed settling overhead, the dwell); the best pair is the next dwell and its length.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from planner.belief import SourceBelief
from radseek.dataset import Frames, Wall

#: m, central-difference step of the source-position derivatives
_H = 1e-3
#: the pose-error models of the score (see the module docstring)
DRIFT_MODELS = ("random_walk", "independent")
#: transit frames per pose group under the random walk (``estimator.mle.TRANSIT_CHUNK``: ~1 m of flight)
TRANSIT_CHUNK = 10
#: m^2, the smallest variance increment between consecutive groups (``estimator.mle._MIN_INCREMENT``): a
#: hover adds no drift, and a zero increment would make the walk's precision infinite
MIN_INCREMENT = 1e-6


@dataclass(frozen=True)
class InfoConfig:
    """Settings of the information planner."""

    dwell_lengths_s: tuple[float, ...] = (5.0, 10.0, 15.0)  # s of dwell clock: the lengths compared per node
    overhead_s: float = 3.0  # s per leg beside flight and dwell: accelerating, settling at the point
    speed_m_s: float = 1.0  # m/s, the leg speed the flight time is charged at
    prior_sd_m: float = 10.0  # m, weak prior on the source's x, y (keeps C finite before the counts pin it)
    drift: str = "random_walk"  # the pose errors: one random walk along the path, or independent per dwell
    landmarks: bool = True  # a pose offset moves the detector alone (mapped walls tell the drift), or the world
    #: 1/m, the mapped walls' attenuation the score assumes while no flown line of sight has crossed one (the
    #: in-flight fit has none to estimate then, and mu = 0 would hide the shadow edges that tell the drift): the
    #: walled model's start value (``estimator.model.WallAttenuation``); 0 plans as if walls did not attenuate
    wall_mu_prior_per_m: float = 1.0

    def __post_init__(self) -> None:
        if self.drift not in DRIFT_MODELS:
            raise ValueError(f"drift must be one of {DRIFT_MODELS}, got {self.drift!r}")
        if not self.dwell_lengths_s or min(self.dwell_lengths_s) <= 0:
            raise ValueError("dwell_lengths_s must be a non-empty tuple of lengths > 0")
        if self.overhead_s < 0 or self.speed_m_s <= 0 or self.prior_sd_m <= 0 or self.wall_mu_prior_per_m < 0:
            raise ValueError("need overhead_s >= 0, speed_m_s > 0, prior_sd_m > 0 and wall_mu_prior_per_m >= 0")


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


def offset_gradient(points: np.ndarray, belief: SourceBelief, walls: Sequence[Wall] = (),
                    wall_mu_per_m: float = 0.0) -> np.ndarray:
    """d lambda / d e_xy (N, 2) at points (N, 3): how the rate a detector at a recorded pose measures moves with
    the pose's x-y offset e when the offset moves the detector alone and the mapped walls stay where the map has
    them (``pose_aware_crlb(landmarks=True)``), i.e. the rate's gradient in the detector's position. Without
    attenuating walls it is -d lambda / d p_s (the inverse square depends on p - p_s only), bit for bit the
    landmark-free derivative; at a wall's shadow edge it is not, and that difference is what pins the drift."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    if not (walls and wall_mu_per_m > 0):
        return -rate_and_gradient(pts, belief)[1][:, :2]
    out = np.empty((len(pts), 2))
    for k in range(2):
        step = np.zeros(3)
        step[k] = _H
        out[:, k] = (belief.predicted_net_rate(pts + step, walls, wall_mu_per_m)
                     - belief.predicted_net_rate(pts - step, walls, wall_mu_per_m)) / (2 * _H)
    return out


def measurement_weight(rate: np.ndarray, grad: np.ndarray, dwell_s: np.ndarray | float,
                       pose_var: np.ndarray) -> np.ndarray:
    """c of J = c g g^T: 1 / (lambda / T + g_d^T Sigma_p g_d) for measurements (N,) with diagonal pose
    variances (N, 3) (only x, y enter: the model's source height is fixed, and d lambda / d p = -g_xy)."""
    var = np.asarray(pose_var, dtype=float).reshape(-1, 3)
    drift = (grad[:, :2] ** 2 * var[:, :2]).sum(-1)
    return 1.0 / (np.asarray(rate) / np.asarray(dwell_s, dtype=float) + drift)


def theta_prior(belief: SourceBelief, prior_sd_m: float = 10.0) -> np.ndarray:
    """(4, 4) weak prior information on theta: ``prior_sd_m`` on x_s, y_s; 100 % on S; the background's
    Poisson sd over 1 s."""
    return np.diag([prior_sd_m**-2, prior_sd_m**-2, belief.cps_at_1m**-2, 1.0 / max(belief.background_cps, 1.0)])


def flown_information(frames: Frames | None, belief: SourceBelief, walls: Sequence[Wall] = (),
                      wall_mu_per_m: float = 0.0, prior_sd_m: float = 10.0) -> np.ndarray:
    """Fisher information (4, 4) over theta of the flown frames under their pose variances: each dwell pooled
    into one measurement at its mean pose (one pose error for the hover), each transit frame on its own; plus
    a weak prior (``prior_sd_m`` on x_s, y_s; 100 % on S; the background's Poisson sd over 1 s)."""
    prior = theta_prior(belief, prior_sd_m)
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


def pose_groups(frames: Frames) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The random walk's pose groups of time-ordered frames, as the estimator cuts them
    (``estimator.mle.PoseGroups``): a dwell's run of frames, transit runs cut every ``TRANSIT_CHUNK`` frames,
    a new walk where ``frames.walk`` changes. Returns the group of each frame (N,), each group's x-y
    variance increment (G, 2) (growth of the mean recorded variance over the group before, >= ``MIN_INCREMENT``;
    a walk's first group: its own variance) and which groups start a walk (G,) bool."""
    dwell = np.asarray(frames.dwell)
    n = len(dwell)
    walk = np.zeros(n, dtype=bool)
    walk[:1] = True
    if frames.walk is not None and n:
        w = np.asarray(frames.walk)
        walk[1:] = w[1:] != w[:-1]
    starts = np.r_[True, dwell[1:] != dwell[:-1]] | walk if n else np.zeros(0, dtype=bool)
    run = np.cumsum(starts) - 1
    first = np.flatnonzero(starts)
    within = np.arange(n) - first[run]
    starts = starts | ((dwell < 0) & (within % TRANSIT_CHUNK == 0))
    index = np.cumsum(starts) - 1
    g = int(index[-1]) + 1 if n else 0
    counts = np.maximum(np.bincount(index, minlength=g), 1)
    var = np.column_stack([np.bincount(index, weights=np.nan_to_num(np.asarray(v, dtype=float), nan=0.0,
                                                                     posinf=0.0, neginf=0.0), minlength=g) / counts
                           for v in (frames.var_x, frames.var_y)])
    restarts = np.zeros(g, dtype=bool)
    restarts[index[walk]] = True
    step = np.diff(var, axis=0, prepend=np.zeros((1, 2)))
    step[restarts] = var[restarts]
    return index, np.maximum(step, MIN_INCREMENT), restarts


def walk_precision(increments: np.ndarray, restarts: np.ndarray | None = None) -> np.ndarray:
    """(2G, 2G) prior precision of the x-y offsets (e_0x, e_0y, e_1x, ...) of a random walk with increment
    variances (G, 2): e_0 ~ N(0, inc_0), e_g - e_(g-1) ~ N(0, inc_g); a group in ``restarts`` starts a new
    walk (no link to the group before it)."""
    inc = np.asarray(increments, dtype=float).reshape(-1, 2)
    g = len(inc)
    w = 1.0 / inc  # (G, 2) precision of each step
    link = w.copy()
    link[0] = 0.0
    if restarts is not None:
        link[np.asarray(restarts, dtype=bool)] = 0.0
    diag = w + np.concatenate((link[1:], np.zeros((1, 2))))
    lam = np.diag(diag.ravel())
    off = -link[1:].ravel()  # coupling of (g, axis) with (g - 1, axis): offset 2 in the stacked order
    idx = np.arange(2, 2 * g)
    lam[idx, idx - 2] = off
    lam[idx - 2, idx] = off
    return lam


def hybrid_information(grad: np.ndarray, weight: np.ndarray, group: np.ndarray, increments: np.ndarray,
                       prior: np.ndarray, restarts: np.ndarray | None = None,
                       offset_grad: np.ndarray | None = None) -> np.ndarray:
    """(4 + 2G)^2 hybrid information over (theta, e_0..e_(G-1)) of measurements with count gradients grad (N, 4)
    and Fisher weights (N,) (T / lambda), each measured at its group's x-y offset (N,) (derivative
    ``offset_grad`` (N, 2); None: -g_xy, the offset moving the whole world), the offsets under the random-walk
    prior of ``increments`` (G, 2), theta under ``prior`` (4, 4): Fisher in theta, Bayesian in the offsets
    (van Trees; ``pose_aware_crlb``)."""
    grad = np.asarray(grad, dtype=float).reshape(-1, 4)
    gd = -grad[:, :2] if offset_grad is None else np.asarray(offset_grad, dtype=float).reshape(-1, 2)
    c = np.asarray(weight, dtype=float).reshape(-1)
    group = np.asarray(group, dtype=int).reshape(-1)
    g = len(np.asarray(increments).reshape(-1, 2))
    h = np.zeros((len(grad), 4 + 2 * g))
    h[:, :4] = grad
    cols = 4 + 2 * group
    rows = np.arange(len(grad))
    h[rows, cols] = gd[:, 0]
    h[rows, cols + 1] = gd[:, 1]
    out = (h * c[:, None]).T @ h
    out[:4, :4] += prior
    out[4:, 4:] += walk_precision(increments, restarts)
    return out


def flown_joint_covariance(frames: Frames | None, belief: SourceBelief, walls: Sequence[Wall] = (),
                           wall_mu_per_m: float = 0.0, prior_sd_m: float = 10.0, landmarks: bool = True
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Covariance (6, 6) of (theta, e_last) after the flown frames under the random walk (the Schur
    complement of every earlier offset), and the last group's x-y variance (2,) (zeros: nothing flown,
    e_last = 0 exactly). Frames are kept one measurement each (rate and gradient at their recorded pose);
    ``landmarks``: the offsets move the detector alone (:func:`offset_gradient`), else the whole world."""
    prior = theta_prior(belief, prior_sd_m)
    n = 0 if frames is None else len(frames.t)
    if n == 0:
        out = np.zeros((6, 6))
        out[:4, :4] = np.linalg.inv(prior)
        return out, np.zeros(2)
    pos = np.column_stack([frames.x, frames.y, frames.z]).astype(float)
    dur = np.asarray(frames.duration, dtype=float)
    group, inc, restarts = pose_groups(frames)
    rate, grad = rate_and_gradient(pos, belief, walls, wall_mu_per_m)
    gd = offset_gradient(pos, belief, walls, wall_mu_per_m) if landmarks else None
    hyb = hybrid_information(grad, dur / np.maximum(rate, 1e-12), group, inc, prior, restarts, gd)
    k = hyb.shape[0]
    sel = np.r_[0:4, k - 2:k]
    rhs = np.zeros((k, 6))
    rhs[sel, np.arange(6)] = 1.0
    cov = np.linalg.solve(hyb, rhs)[sel]
    last_walk = int(np.flatnonzero(restarts)[-1])
    return 0.5 * (cov + cov.T), inc[last_walk:].sum(0)


def joint_gain(cov6: np.ndarray, grad: np.ndarray, drift_var: np.ndarray, c: np.ndarray,
               offset_grad: np.ndarray | None = None) -> np.ndarray:
    """x-y D-optimal gain (nats) of a measurement with Fisher weight c (N,) or (N, L) and count gradient
    grad (N, 4), taken at e_new = e_last + w, w ~ N(0, drift_var (N, 2)), given the joint covariance (6, 6) of
    (theta, e_last): the rank-one update of P' = P + diag(0, drift_var) with h = (g, d lambda / d e)
    (``offset_grad`` (N, 2); None: -g_xy)."""
    grad = np.asarray(grad, dtype=float).reshape(-1, 4)
    a = np.asarray(drift_var, dtype=float).reshape(-1, 2)
    gd = -grad[:, :2] if offset_grad is None else np.asarray(offset_grad, dtype=float).reshape(-1, 2)
    h = np.concatenate((grad, gd), axis=1)  # (N, 6)
    v = h @ cov6  # (N, 6) = (P h)^T
    v[:, 4:] += a * h[:, 4:]
    q = (v * h).sum(-1)  # h^T P' h
    cxy_inv = np.linalg.inv(cov6[:2, :2])
    s = np.einsum("ni,ij,nj->n", v[:, :2], cxy_inv, v[:, :2])
    c = np.asarray(c, dtype=float)
    shape = (-1,) + (1,) * (c.ndim - 1)
    ratio = c * s.reshape(shape) / (1.0 + c * q.reshape(shape))
    return -np.log(np.clip(1.0 - ratio, 1e-300, 1.0))


def joint_bound_after(cov6: np.ndarray, grad: np.ndarray, drift_var: np.ndarray, c: np.ndarray,
                      offset_grad: np.ndarray | None = None) -> np.ndarray:
    """The x-y bound (m, sqrt of the trace of the x-y covariance: ``estimator.inflight.bound_m``) after the
    measurement of :func:`joint_gain` (same arguments), (N,) or (N, L) as c: the A-optimal side of the same
    rank-one update, trace(C_xy) - c |u|^2 / (1 + c h^T P' h)."""
    grad = np.asarray(grad, dtype=float).reshape(-1, 4)
    a = np.asarray(drift_var, dtype=float).reshape(-1, 2)
    gd = -grad[:, :2] if offset_grad is None else np.asarray(offset_grad, dtype=float).reshape(-1, 2)
    h = np.concatenate((grad, gd), axis=1)
    v = h @ cov6
    v[:, 4:] += a * h[:, 4:]
    q = (v * h).sum(-1)
    uu = (v[:, :2] ** 2).sum(-1)
    c = np.asarray(c, dtype=float)
    shape = (-1,) + (1,) * (c.ndim - 1)
    trace = float(np.trace(cov6[:2, :2])) - c * uu.reshape(shape) / (1.0 + c * q.reshape(shape))
    return np.sqrt(np.clip(trace, 0.0, None))


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
    """Per node: the best information rate (nats/s), its gain (nats) and dwell length (s); with the random-walk
    drift also the x-y bound of the flown frames now (m, the bound the estimator reaches: landmark-aware with
    ``InfoConfig.landmarks``) and, per node, the largest expected fall of that bound per second of the leg
    (m/s, over the dwell lengths): what one more dwell there is worth to the stop rule (``mission.search``)."""

    rate: np.ndarray
    gain: np.ndarray
    dwell_s: np.ndarray
    bound_m: float = float("nan")
    fall_m_s: np.ndarray | None = None


def score_information(positions: np.ndarray, path_length: np.ndarray, belief: SourceBelief, frames: Frames | None,
                      pose_var_now: np.ndarray, config: InfoConfig = InfoConfig(), walls: Sequence[Wall] = (),
                      wall_mu_per_m: float = 0.0) -> InfoScores:
    """Score candidate nodes (N, 3) reached after ``path_length`` (N,) m from a pose of variance
    ``pose_var_now`` (3,) after ``frames`` (None: nothing flown): the expected x-y D-optimal gain per second
    of each dwell length, the best kept."""
    pos = np.asarray(positions, dtype=float).reshape(-1, 3)
    length = np.maximum(np.asarray(path_length, dtype=float).reshape(-1), 0.0)
    rate, grad = rate_and_gradient(pos, belief, walls, wall_mu_per_m)
    lengths = np.asarray(config.dwell_lengths_s, dtype=float)
    now = np.asarray(pose_var_now, dtype=float).reshape(3)
    if config.drift == "random_walk":
        cov6, last_var = flown_joint_covariance(frames, belief, walls, wall_mu_per_m, config.prior_sd_m,
                                                config.landmarks)
        drift = np.maximum(now[:2] - last_var, 0.0)[None, :] + length[:, None] * belief.drift_density[None, :2]
        gd = offset_gradient(pos, belief, walls, wall_mu_per_m) if config.landmarks else None
        c = lengths[None, :] / np.maximum(rate, 1e-12)[:, None]
        gain = joint_gain(cov6, grad, drift, c, gd)
        bound = float(np.sqrt(max(float(np.trace(cov6[:2, :2])), 0.0)))
        after = joint_bound_after(cov6, grad, drift, c, gd)
    else:
        cov = np.linalg.inv(flown_information(frames, belief, walls, wall_mu_per_m, config.prior_sd_m))
        cov = 0.5 * (cov + cov.T)
        var = now[None, :] + length[:, None] * belief.drift_density
        c = np.column_stack([measurement_weight(rate, grad, t, var) for t in lengths])  # (N, L)
        gain = xy_gain(cov, grad, c)
    leg_s = length[:, None] / config.speed_m_s + config.overhead_s + lengths[None, :]
    per_s = gain / leg_s
    best = np.argmax(per_s, axis=1)
    idx = np.arange(len(pos))
    if config.drift != "random_walk":
        return InfoScores(rate=per_s[idx, best], gain=gain[idx, best], dwell_s=lengths[best])
    return InfoScores(rate=per_s[idx, best], gain=gain[idx, best], dwell_s=lengths[best], bound_m=bound,
                      fall_m_s=((bound - after) / leg_s).max(axis=1))
