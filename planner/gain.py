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
