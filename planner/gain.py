"""Next-best-dwell-point gain of paper 003 eq. 6, vectorised over candidate nodes.

Eq. 6 as printed::

    Gain(n_i) = r_is^2 / delta^2 * exp(-r_is^2 / delta^2) * prod_{j != i}^{N_d} exp(-r_ij^2 / (2 N_d))

with r_is the distance of node i to the source estimate, r_ij to the previous dwell point j, N_d the
number of dwell points, and "delta, zeta tunable factors that control the maximum" (Fig. 4 uses
delta = 1, zeta = 1.85). The printed text has two defects we must resolve:

1. zeta appears nowhere in the printed formula; the only free constant is the "2" in 2 N_d, which we
   read as zeta (an extraction of the Greek letter as a digit), so zeta = 2 is the printed form;
2. each printed factor exp(-r_ij^2 / ...) is *largest at* a previous dwell point, which contradicts
   the paper's own text ("keep distance from all the previous dwell points") and Fig. 4. We use the
   complement, (1 - exp(-r_ij^2 / (zeta N_d))): zero at a previous dwell point, -> 1 far from all of
   them, so the source term (maximal at r_is = delta) sets the maximum.

``gain_eq6`` implements that reading (the planner's gain); ``gain_eq6_as_printed`` the literal formula,
kept so tests can show why it is not used. Distances are Euclidean in position (x, y, z): the source
configuration xi_s has no meaningful yaw. Gain values lie in [0, 1/e].

``gain_eq6_pose`` is eq. 6 under pose covariance (the design card's "dwell-point gain under pose
covariance"): eq. 6 times :func:`pose_information_factor`, the share of the dwell's expected information
(posterior-trace reduction, paper 004 eq. 4.7-4.9 and 5.3-5.6) left once the odometry drift its path adds
is charged; identical to eq. 6 at zero drift density.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class GainConfig:
    """Tunable factors of eq. 6 (paper 003 Fig. 4: delta = 1, zeta = 1.85)."""

    delta: float = 1.0  # m, > 0: distance to the source estimate at which the source term peaks
    zeta: float = 1.85  # m^2 per dwell point, > 0: spread of the repulsion from previous dwell points

    def __post_init__(self) -> None:
        if self.delta <= 0 or self.zeta <= 0:
            raise ValueError("delta and zeta must be > 0")


def source_term(nodes: np.ndarray, source: np.ndarray, delta: float) -> np.ndarray:
    """r^2/delta^2 * exp(-r^2/delta^2) of eq. 6 for nodes (N, 3): peaks at r = delta with value 1/e."""
    u = ((np.asarray(nodes, dtype=float) - np.asarray(source, dtype=float)) ** 2).sum(-1) / delta**2
    return u * np.exp(-u)


def _sq_dist(nodes: np.ndarray, dwell_points: np.ndarray) -> np.ndarray:
    n = np.asarray(nodes, dtype=float)
    d = np.asarray(dwell_points, dtype=float).reshape(-1, 3)
    return ((n[..., None, :] - d) ** 2).sum(-1)  # (..., K)


def dwell_repulsion(nodes: np.ndarray, dwell_points: np.ndarray, zeta: float) -> np.ndarray:
    """prod_j (1 - exp(-r_ij^2 / (zeta N_d))) over previous dwell points (K, 3); 1 when K = 0."""
    d = np.asarray(dwell_points, dtype=float).reshape(-1, 3)
    if len(d) == 0:
        return np.ones(np.shape(nodes)[:-1])
    return (-np.expm1(-_sq_dist(nodes, d) / (zeta * len(d)))).prod(-1)


def gain_eq6(nodes: np.ndarray, source: np.ndarray, dwell_points: np.ndarray,
             config: GainConfig = GainConfig()) -> np.ndarray:
    """Gain of paper 003 eq. 6 (with the repulsion read as above) for nodes (N, 3) -> (N,)."""
    return source_term(nodes, source, config.delta) * dwell_repulsion(nodes, dwell_points, config.zeta)


def gain_eq6_as_printed(nodes: np.ndarray, source: np.ndarray, dwell_points: np.ndarray,
                        delta: float = 1.0) -> np.ndarray:
    """Literal printed eq. 6: source term * prod_j exp(-r_ij^2 / (2 N_d)). Not used by the planner."""
    d = np.asarray(dwell_points, dtype=float).reshape(-1, 3)
    rep = np.exp(-_sq_dist(nodes, d).sum(-1) / (2 * len(d))) if len(d) else 1.0
    return source_term(nodes, source, delta) * rep


# ----------------------------------------------------------------------------------- gain under pose covariance


def rate_gradient(nodes: np.ndarray, source: np.ndarray, cps_at_1m: float) -> np.ndarray:
    """d lambda / d p_s (cps/m) of the inverse-square rate lambda = A / r^2 at nodes (N, 3) -> (N, 3).

    Paper 004 eq. 5.5-5.6 (there in 2-D): d lambda / d x_0 = -2 A (x_0 - x_k) / r^4, here in 3-D,
    i.e. 2 A (p - p_s) / r^4. The rate depends on p - p_s only, so d lambda / d p = -d lambda / d p_s.
    """
    d = np.asarray(nodes, dtype=float) - np.asarray(source, dtype=float)
    r2 = np.maximum((d**2).sum(-1), 1e-6)
    return 2.0 * cps_at_1m * d / r2[..., None] ** 2


def pose_information_factor(nodes: np.ndarray, path_length: np.ndarray, source: np.ndarray,
                            source_covariance: np.ndarray, cps_at_1m: float, background_cps: float,
                            drift_density: np.ndarray | float, dwell_s: float = 10.0) -> np.ndarray:
    """Fraction kappa in [0, 1] of a dwell's value that survives the pose drift its path adds: (N,) for
    nodes (N, 3) reached after ``path_length`` (N,) metres.

    Linearise the dwell's mean rate about the belief (mean p_s, covariance Sigma_s, drift included, as the
    in-flight estimate reports it) and the planned pose:

        y = lambda(p - p_s - e) ~ lambda_0 - g^T (u - mean) + n,   u = p_s + e,
        g = d lambda / d p_s (paper 004 eq. 5.5-5.6),   var n = s2 = lambda / T (Poisson, paper 004 eq. 5.3),

    where e ~ N(0, Sigma_p), Sigma_p = diag(drift_density) * L, is the odometry drift the path adds (a
    random walk in distance flown: variance density x length). The dwell measures the source in the
    drifted frame, u, whose prior is Sigma_u = Sigma_s + Sigma_p; and because a random walk never
    returns, e stays in every later pose too, so the world-frame posterior of the source carries it in full.
    The expected reduction of the source's posterior covariance trace (a rank-one Kalman update: the
    Gaussian form of the expected information gain of paper 004 eq. 4.7-4.9) is

        Delta(Sigma_p) = |Sigma_u g|^2 / (s2 + g^T Sigma_u g) - tr Sigma_p,

    and kappa = max(Delta(Sigma_p), 0) / Delta(0). Kalman updates are monotone in the prior, so
    Delta(Sigma_p) <= Delta(0): kappa = 1 at zero density or zero path, and falls with the path length,
    the faster the tighter the belief already is (late in the search a metre flown adds drift the dwell
    cannot measure away; early the dwell's information dominates). ``lambda`` is the gross rate
    cps_at_1m / r^2 + background.
    """
    pos = np.asarray(nodes, dtype=float).reshape(-1, 3)
    length = np.maximum(np.asarray(path_length, dtype=float).reshape(-1), 0.0)
    dens = np.broadcast_to(np.asarray(drift_density, dtype=float), (3,))
    if not np.any(dens > 0):
        return np.ones(len(pos))
    src = np.asarray(source, dtype=float).reshape(3)
    cov = np.asarray(source_covariance, dtype=float).reshape(3, 3)
    g = rate_gradient(pos, src, cps_at_1m)
    s2 = (cps_at_1m / np.maximum(((pos - src) ** 2).sum(-1), 1e-6) + background_cps) / dwell_s

    def reduction(extra: np.ndarray) -> np.ndarray:  # extra (N, 3): diagonal of Sigma_p per node
        sg = g @ cov + extra * g  # (Sigma_s + Sigma_p) g, (N, 3)
        return (sg**2).sum(-1) / (s2 + (sg * g).sum(-1)) - extra.sum(-1)

    base = reduction(np.zeros_like(pos))
    with np.errstate(divide="ignore", invalid="ignore"):
        kappa = np.clip(reduction(length[:, None] * dens) / base, 0.0, 1.0)
    return np.where(base > 0, kappa, np.where(length > 0, 0.0, 1.0))


def gain_eq6_pose(nodes: np.ndarray, source: np.ndarray, dwell_points: np.ndarray, path_length: np.ndarray,
                  source_covariance: np.ndarray, cps_at_1m: float, background_cps: float,
                  drift_density: np.ndarray | float, config: GainConfig = GainConfig(),
                  dwell_s: float = 10.0) -> np.ndarray:
    """Eq. 6 under pose covariance: ``gain_eq6`` x :func:`pose_information_factor` for nodes (N, 3).

    Equals ``gain_eq6`` when ``drift_density`` is zero; with drift, of two nodes with equal eq. 6 gain the
    one reached by the shorter path wins.
    """
    return gain_eq6(nodes, source, dwell_points, config) * pose_information_factor(
        nodes, path_length, source, source_covariance, cps_at_1m, background_cps, drift_density, dwell_s)
