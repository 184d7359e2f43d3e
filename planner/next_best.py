"""Next-best dwell point (paper 003 sec. IV-B-3): grow a tree, score nodes with eq. 6, apply the
constraints, extract the path to the best node and choose the yaw along it.

Three scores (``NextBestConfig.gain_kind``): ``"eq6"``, paper 003 eq. 6 alone, and ``"eq6_pose"``, eq. 6
under pose covariance (``planner.gain.gain_eq6_pose``): the drift variance a candidate's path adds
(``SourceBelief.drift_density`` x path length, the path being the straight segment when it is free,
else the tree path) discounts the information the dwell can give, so of two equally informative
candidates the nearer wins. With zero drift density both gains are the same. ``"info"``: the information
planner (``planner.information``): the expected D-optimal reduction of the source's x-y covariance given
the flown frames, under the drift the path adds, per second of the leg; it also picks the dwell length
(``DwellPlan.info["dwell_s"]``).

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

import math
import time
from dataclasses import dataclass, field

import numpy as np

from planner.belief import DwellHistory, SourceBelief
from planner.dwell_tree import Tree, TreeConfig, densify, grow_tree, shortcut_path
from planner.gain import GainConfig, gain_eq6, gain_eq6_pose
from planner.information import InfoConfig, score_information
from planner.occupancy import OccupancyMap
from planner.plan import DwellPlan
from planner.yaw_sampling import bearing_score, bearings, sample_yaw, track_yaw
from radseek.dataset import Frames

GAIN_KINDS = ("eq6", "eq6_pose", "info")


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
    gain_kind: str = "eq6"  # one of GAIN_KINDS: eq. 6, or eq. 6 under the pose covariance the path adds
    dwell_s: float = 10.0  # s, > 0: dwell length assumed by the pose-covariance gain's counting noise
    info: InfoConfig = field(default_factory=InfoConfig)  # the information planner's settings ("info")

    def __post_init__(self) -> None:
        if self.lambda_min_cps < 0 or self.ellipsoid_sigma < 0 or self.wall_mu_per_m < 0:
            raise ValueError("lambda_min_cps, ellipsoid_sigma and wall_mu_per_m must be >= 0")
        if self.gain_kind not in GAIN_KINDS:
            raise ValueError(f"gain_kind must be one of {GAIN_KINDS}, got {self.gain_kind!r}")
        if not self.dwell_s > 0:
            raise ValueError("dwell_s must be > 0")
        if self.nu < 2 or self.q < 1:
            raise ValueError("need nu >= 2 and q >= 1")


@dataclass(frozen=True)
class NodeScores:
    """Per-node gain (N,) and the constraint masks (N,) used to pick the best node."""

    gain: np.ndarray
    too_close: np.ndarray  # inside the covariance semi-major axis
    too_weak: np.ndarray  # predicted net rate below lambda_min
    valid: np.ndarray  # candidate: neither, and not the root
    dwell_s: np.ndarray | None = None  # (N,) s, the dwell length each node's score assumes ("info" only)
    bound_m: float = float("nan")  # m, the x-y bound of the flown frames ("info" only: ``InfoScores.bound_m``)
    fall_m_s: np.ndarray | None = None  # (N,) m/s, its largest expected fall per second of each leg ("info")

    @property
    def best(self) -> int:
        """Index of the valid node with the largest gain, -1 if none is valid."""
        if not self.valid.any():
            return -1
        return int(np.argmax(np.where(self.valid, self.gain, -np.inf)))


def score_nodes(positions: np.ndarray, belief: SourceBelief, history: DwellHistory, occ: OccupancyMap,
                config: NextBestConfig = NextBestConfig(), pose_covariance: np.ndarray | None = None,
                root: int | None = 0, path_length: np.ndarray | None = None, frames: Frames | None = None,
                pose_var_now: np.ndarray | None = None) -> NodeScores:
    """Gain (``config.gain_kind``) and constraints for node positions (N, 3); ``root`` (index or None) is
    excluded. ``path_length`` (N,) m: how far each node is flown from the current pose (the
    pose-covariance gain and the information planner need it; None: straight-line distance from
    ``positions[root]``, or zero). ``frames`` (the flown frames) and ``pose_var_now`` ((3,) m^2, the pose
    variance now) are what the information planner's score starts from (None: nothing flown, exact pose)."""
    pos = np.asarray(positions, dtype=float).reshape(-1, 3)
    if path_length is None:
        path_length = (np.linalg.norm(pos - pos[root], axis=1) if root is not None and len(pos)
                       else np.zeros(len(pos)))
    dwell_s = fall = None
    bound = float("nan")
    if config.gain_kind == "info":
        info = score_information(pos, path_length, belief, frames,
                                 np.zeros(3) if pose_var_now is None else pose_var_now,
                                 config.info, occ.walls, config.wall_mu_per_m)
        gain, dwell_s, bound, fall = info.rate, info.dwell_s, info.bound_m, info.fall_m_s
    elif config.gain_kind == "eq6_pose":
        gain = gain_eq6_pose(pos, belief.mean, history.positions, path_length, belief.covariance,
                             belief.cps_at_1m, belief.background_cps, belief.drift_density, config.gain,
                             config.dwell_s)
    else:
        gain = gain_eq6(pos, belief.mean, history.positions, config.gain)
    a = config.ellipsoid_sigma * belief.semi_major_axis(pose_covariance)
    too_close = np.linalg.norm(pos - belief.mean, axis=1) < a
    rate = belief.predicted_net_rate(pos, occ.walls, config.wall_mu_per_m)
    too_weak = rate < config.lambda_min_cps
    valid = ~too_close & ~too_weak
    if root is not None and len(valid):
        valid[root] = False
    return NodeScores(gain=gain, too_close=too_close, too_weak=too_weak, valid=valid, dwell_s=dwell_s,
                      bound_m=bound, fall_m_s=fall)


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
                    rng: np.random.Generator | None = None, tree: Tree | None = None, frames: Frames | None = None,
                    pose_var_now: np.ndarray | None = None) -> DwellPlan:
    """Paper 003 sec. IV-B-3 next-best dwell point from ``current`` = (x, y, z, psi).

    Pass ``tree`` to score an existing tree (tests); otherwise one is grown with ``config.tree``.
    ``frames`` and ``pose_var_now``: see :func:`score_nodes` (the information planner's inputs).
    """
    rng = rng if rng is not None else np.random.default_rng()
    current = np.asarray(current, dtype=float).reshape(4)
    t0 = time.perf_counter()
    tree = tree if tree is not None else grow_tree(current, occ, config.tree)
    t_tree = time.perf_counter() - t0
    pos = tree.states[:, :3]
    length = None
    if config.gain_kind in ("eq6_pose", "info"):  # what will be flown: the straight segment if free, else the tree path
        straight = occ.segments_valid(np.broadcast_to(pos[0], pos.shape), pos)
        length = np.where(straight, np.linalg.norm(pos - pos[0], axis=1), tree.path_lengths())
    scores = score_nodes(pos, belief, history, occ, config, pose_covariance, path_length=length, frames=frames,
                         pose_var_now=pose_var_now)
    info = {
        "nodes": len(tree), "tree_time_s": t_tree, "valid_nodes": int(scores.valid.sum()),
        "rejected_close": int(scores.too_close.sum()), "rejected_weak": int(scores.too_weak.sum()),
    }
    if scores.fall_m_s is not None:
        # the stop rule's inputs (``mission.search``): the bound now and the most a valid next leg can take off
        # it per second (nan: no valid node)
        info["bound_m"] = scores.bound_m
        info["bound_fall_m_s"] = float(scores.fall_m_s[scores.valid].max()) if scores.valid.any() else math.nan
    best = scores.best
    if best < 0:
        info["plan_time_s"] = time.perf_counter() - t0
        return DwellPlan(np.zeros((0, 4)), np.zeros((0, 4)), f"next_best_{config.gain_kind}", info=info)
    path = finish_path(tree.path_to(best), current[3], belief.mean, occ, config, rng)
    info["plan_time_s"] = time.perf_counter() - t0
    info["best_node"] = best
    if length is not None:
        info["path_length_m"] = float(length[best])
    if scores.dwell_s is not None:
        info["dwell_s"] = float(scores.dwell_s[best])
    return DwellPlan(path[-1:], path, f"next_best_{config.gain_kind}", gains=scores.gain[best:best + 1], info=info)
