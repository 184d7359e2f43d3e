"""Next-best dwell point (paper 003 sec. IV-B-3): grow a tree, score nodes with eq. 6, apply the
constraints, extract the path to the best node and choose the yaw along it.

Constraints on candidate nodes (paper 003, text after eq. 6):

* nodes "closer than 1 semi-major axis of the ellipsoid corresponding to the position covariance" are
  invalid: distance to the source mean < sqrt(largest eigenvalue of Sigma_source + Sigma_pose);
* nodes where the predicted net rate lambda = cps_at_1m / r^2 (times wall attenuation if a coefficient
  is given) falls below lambda_min are invalid;
* the root (current configuration) is not a candidate.

The returned ``DwellPlan`` holds one dwell point (the best node, yaw facing the source estimate when
the yaw-rate limit allows) and the shortcut, collision-free path from the current configuration.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from planner.belief import DwellHistory, SourceBelief
from planner.dwell_tree import Tree, TreeConfig, densify, grow_tree, shortcut_path
from planner.gain import GainConfig, gain_eq6
from planner.occupancy import OccupancyMap
from planner.plan import DwellPlan
from planner.yaw_sampling import bearing_score, bearings, sample_yaw, track_yaw


@dataclass(frozen=True)
class NextBestConfig:
    """Scoring and yaw settings; ``tree`` and ``gain`` hold the tree and eq. 6 settings."""

    tree: TreeConfig = field(default_factory=TreeConfig)
    gain: GainConfig = field(default_factory=GainConfig)
    lambda_min_cps: float = 1.0  # cps, >= 0: predicted net rate floor (paper: lambda_min -> 0)
    ellipsoid_sigma: float = 1.0  # >= 0: reject nodes within this many semi-major axes of the belief
    wall_mu_per_m: float = 0.0  # 1/m, >= 0: wall attenuation used in the rate prediction (0 = ignore)
    nu: int = 12  # path samples for the yaw choice (paper's nu), >= 2
    q: int = 8  # random yaw candidates per sample (paper's q), >= 1

    def __post_init__(self) -> None:
        if self.lambda_min_cps < 0 or self.ellipsoid_sigma < 0 or self.wall_mu_per_m < 0:
            raise ValueError("lambda_min_cps, ellipsoid_sigma and wall_mu_per_m must be >= 0")
        if self.nu < 2 or self.q < 1:
            raise ValueError("need nu >= 2 and q >= 1")


@dataclass(frozen=True)
class NodeScores:
    """Per-node gain (N,) and the constraint masks (N,) used to pick the best node."""

    gain: np.ndarray
    too_close: np.ndarray  # inside the covariance semi-major axis
    too_weak: np.ndarray  # predicted net rate below lambda_min
    valid: np.ndarray  # candidate: neither, and not the root

    @property
    def best(self) -> int:
        """Index of the valid node with the largest gain, -1 if none is valid."""
        if not self.valid.any():
            return -1
        return int(np.argmax(np.where(self.valid, self.gain, -np.inf)))


def score_nodes(positions: np.ndarray, belief: SourceBelief, history: DwellHistory, occ: OccupancyMap,
                config: NextBestConfig = NextBestConfig(), pose_covariance: np.ndarray | None = None,
                root: int | None = 0) -> NodeScores:
    """Eq. 6 gain and constraints for node positions (N, 3); ``root`` (index or None) is excluded."""
    pos = np.asarray(positions, dtype=float).reshape(-1, 3)
    gain = gain_eq6(pos, belief.mean, history.positions, config.gain)
    a = config.ellipsoid_sigma * belief.semi_major_axis(pose_covariance)
    too_close = np.linalg.norm(pos - belief.mean, axis=1) < a
    rate = belief.predicted_net_rate(pos, occ.walls, config.wall_mu_per_m)
    too_weak = rate < config.lambda_min_cps
    valid = ~too_close & ~too_weak
    if root is not None and len(valid):
        valid[root] = False
    return NodeScores(gain=gain, too_close=too_close, too_weak=too_weak, valid=valid)


def finish_path(tree_path: np.ndarray, start_yaw: float, belief_mean: np.ndarray, occ: OccupancyMap,
                config: NextBestConfig, rng: np.random.Generator) -> np.ndarray:
    """Shortcut a tree path, add the nu samples and choose the yaw: (M, 4) collision-free."""
    pts = densify(shortcut_path(tree_path, occ), config.nu)
    # deterministic candidates beside the q random ones: the bearing itself and a feasible greedy turn to it
    target = bearings(pts, belief_mean)
    greedy = track_yaw(pts, start_yaw, target, config.tree.speed, config.tree.yaw_rate_max)
    facing = bearing_score(belief_mean)

    def score(points: np.ndarray, yaws: np.ndarray) -> np.ndarray:
        s = facing(points, yaws)
        s[-1] *= len(points)  # the heading while dwelling matters as much as the whole transit
        return s

    yaw = sample_yaw(pts, start_yaw, score, q=config.q, speed=config.tree.speed,
                     yaw_rate_max=config.tree.yaw_rate_max, rng=rng, extra=np.column_stack([target, greedy]))
    return np.column_stack([pts, yaw])


def plan_next_dwell(current: np.ndarray, belief: SourceBelief, history: DwellHistory, occ: OccupancyMap,
                    config: NextBestConfig = NextBestConfig(), pose_covariance: np.ndarray | None = None,
                    rng: np.random.Generator | None = None, tree: Tree | None = None) -> DwellPlan:
    """Paper 003 sec. IV-B-3 next-best dwell point from ``current`` = (x, y, z, psi).

    Pass ``tree`` to score an existing tree (tests); otherwise one is grown with ``config.tree``.
    """
    rng = rng if rng is not None else np.random.default_rng()
    current = np.asarray(current, dtype=float).reshape(4)
    t0 = time.perf_counter()
    tree = tree if tree is not None else grow_tree(current, occ, config.tree)
    t_tree = time.perf_counter() - t0
    scores = score_nodes(tree.states[:, :3], belief, history, occ, config, pose_covariance)
    info = {
        "nodes": len(tree), "tree_time_s": t_tree, "valid_nodes": int(scores.valid.sum()),
        "rejected_close": int(scores.too_close.sum()), "rejected_weak": int(scores.too_weak.sum()),
    }
    best = scores.best
    if best < 0:
        info["plan_time_s"] = time.perf_counter() - t0
        return DwellPlan(np.zeros((0, 4)), np.zeros((0, 4)), "next_best_eq6", info=info)
    path = finish_path(tree.path_to(best), current[3], belief.mean, occ, config, rng)
    info["plan_time_s"] = time.perf_counter() - t0
    info["best_node"] = best
    return DwellPlan(path[-1:], path, "next_best_eq6", gains=scores.gain[best:best + 1], info=info)
