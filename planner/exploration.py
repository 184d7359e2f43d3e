"""Initial exploration until three dwell readings are above background (paper 003 sec. IV-B-2).

Paper 003 explores with its own next-best-view planner and "dwells at each planned exploration
viewpoint"; this step "is disengaged once three radiation readings lambda_k at respective dwell points
above background are detected". We use frontier exploration with the target selection of paper 004
sec. 4.1.1 instead (no volumetric camera map here):

* a 2-D grid at flight altitude over the flight volume; cells within ``sensing_radius`` of a visited
  position are *visited*; *frontier* cells are free, unvisited cells 8-adjacent to visited free cells;
* cost of frontier t for robot i (paper 004 eq. 4.1): V = alpha ||i - t|| + (1 - alpha) D(t), where D
  (eq. 4.2) is the distance of t to the line through the robot along the intensity gradient. The
  gradient comes from a least-squares plane fit of the dwell rates; frontiers *behind* the robot along
  the gradient use their full distance to the robot instead, so the line acts as a ray up the gradient.
  Without a gradient (fewer than 3 non-collinear readings) D = 0: pure nearest frontier;
* the chosen frontier is reached along an OMPL tree (``dwell_tree.grow_tree``): the target is the tree
  node closest (in x, y) to the cheapest frontier that some node reaches within one cell.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import binary_dilation

from planner.belief import DwellHistory
from planner.dwell_tree import TreeConfig, densify, grow_tree, shortcut_path
from planner.occupancy import OccupancyMap
from planner.plan import DwellPlan
from planner.yaw_sampling import sample_yaw, track_yaw


@dataclass(frozen=True)
class FrontierConfig:
    resolution: float = 0.5  # m, > 0: grid cell size
    sensing_radius: float = 1.5  # m, > 0: cells this close to a visited position are visited
    alpha: float = 0.8  # [0, 1], paper 004 eq. 4.1 weight of distance vs gradient-line distance
    altitude: float | None = None  # m: grid altitude (None: the current z)
    k_sigma: float = 3.0  # a reading is above background when lambda - b > k_sigma sqrt(b / dwell_s)
    dwell_s: float = 5.0  # s, typical dwell used in that test
    min_readings: int = 3  # paper 003: three readings above background end exploration
    tree: TreeConfig = field(default_factory=TreeConfig)
    q: int = 8  # random yaw candidates per path sample
    nu: int = 12  # path samples for the yaw choice

    def __post_init__(self) -> None:
        if self.resolution <= 0 or self.sensing_radius <= 0 or not (0 <= self.alpha <= 1):
            raise ValueError("need resolution > 0, sensing_radius > 0 and 0 <= alpha <= 1")


def exploration_done(history: DwellHistory, background_cps: float, config: FrontierConfig = FrontierConfig()
                     ) -> bool:
    """True once ``min_readings`` dwell readings are significantly above background."""
    above = history.above_background(background_cps, config.k_sigma, config.dwell_s)
    return int(above.sum()) >= config.min_readings


def visited_cells(xs: np.ndarray, ys: np.ndarray, positions: np.ndarray, radius: float) -> np.ndarray:
    """(ny, nx) bool: cell centres within ``radius`` (horizontal) of any of positions (K, >=2)."""
    gx, gy = np.meshgrid(xs, ys)
    p = np.asarray(positions, dtype=float)
    if p.size == 0:
        return np.zeros(gx.shape, dtype=bool)
    d2 = (gx[..., None] - p[:, 0]) ** 2 + (gy[..., None] - p[:, 1]) ** 2
    return (d2 <= radius**2).any(-1)


def frontier_cells(occupied: np.ndarray, visited: np.ndarray) -> np.ndarray:
    """(ny, nx) bool: free, unvisited cells 8-adjacent to a visited free cell."""
    free = ~occupied
    seen = visited & free
    return free & ~visited & binary_dilation(seen, structure=np.ones((3, 3), dtype=bool))


def intensity_gradient(history: DwellHistory) -> np.ndarray | None:
    """(2,) cps/m gradient of a least-squares plane rate = c + g . (x, y), None if ill-posed."""
    if len(history) < 3:
        return None
    a = np.column_stack([np.ones(len(history)), history.positions[:, :2]])
    if np.linalg.matrix_rank(a - a.mean(0) * [0, 1, 1]) < 3:
        return None
    coef, *_ = np.linalg.lstsq(a, history.rates, rcond=None)
    g = coef[1:]
    return g if np.linalg.norm(g) > 0 else None


def frontier_cost(cells: np.ndarray, robot: np.ndarray, gradient: np.ndarray | None, alpha: float) -> np.ndarray:
    """Paper 004 eq. 4.1-4.2 for frontier centres (F, 2) and robot (2,): (F,) cost, lower is better."""
    rel = np.asarray(cells, dtype=float) - np.asarray(robot, dtype=float)[:2]
    dist = np.linalg.norm(rel, axis=1)
    if gradient is None:
        return alpha * dist
    u = gradient / np.linalg.norm(gradient)
    along = rel @ u
    line = np.abs(rel[:, 0] * u[1] - rel[:, 1] * u[0])  # eq. 4.2: distance to the gradient line
    return alpha * dist + (1 - alpha) * np.where(along >= 0, line, dist)


def plan_exploration(current: np.ndarray, history: DwellHistory, occ: OccupancyMap,
                     visited_positions: np.ndarray | None = None, config: FrontierConfig = FrontierConfig(),
                     rng: np.random.Generator | None = None) -> DwellPlan:
    """Next exploration dwell point and collision-free path from ``current`` (x, y, z, psi).

    ``visited_positions`` (K, 3): where the vehicle has been (flown path samples); the dwell points of
    ``history`` and the current position always count. Returns an empty plan when no frontier is left.
    """
    rng = rng if rng is not None else np.random.default_rng()
    current = np.asarray(current, dtype=float).reshape(4)
    z = current[2] if config.altitude is None else config.altitude
    xs, ys, occupied = occ.grid(config.resolution, z)
    seen = [current[None, :3], history.positions]
    if visited_positions is not None:
        seen.append(np.asarray(visited_positions, dtype=float).reshape(-1, 3))
    visited = visited_cells(xs, ys, np.concatenate(seen), config.sensing_radius)
    front = frontier_cells(occupied, visited)
    iy, ix = np.nonzero(front)
    info: dict = {"frontier_cells": len(ix)}
    if len(ix) == 0:
        return DwellPlan(np.zeros((0, 4)), np.zeros((0, 4)), "frontier", info=info)
    cells = np.column_stack([xs[ix], ys[iy]])
    gradient = intensity_gradient(history)
    cost = frontier_cost(cells, current[:2], gradient, config.alpha)
    tree = grow_tree(current, occ, config.tree)
    # reachable frontiers: a tree node within one cell (horizontally)
    d2 = ((tree.states[None, :, :2] - cells[:, None, :]) ** 2).sum(-1)  # (F, N)
    near = np.argmin(d2, axis=1)
    reach = d2[np.arange(len(cells)), near] <= config.resolution**2
    info.update(nodes=len(tree), reachable=int(reach.sum()), gradient=None if gradient is None else gradient.tolist())
    straight = None
    if not reach.any():
        # the tree stops at n_min nodes once its time budget has passed (a loaded machine), and in a large
        # field those may miss every frontier cell near a corner start: fly to a cell in a straight line if
        # one is free rather than end the search before its first dwell (outdoor seed 63: "no frontier left")
        ends = np.column_stack([cells, np.full(len(cells), current[2])])
        straight = occ.segments_valid(np.broadcast_to(current[:3], ends.shape), ends)
        info["straight"] = int(straight.sum())
        if not straight.any():
            return DwellPlan(np.zeros((0, 4)), np.zeros((0, 4)), "frontier", info=info)
        reach = straight
    f = int(np.argmin(np.where(reach, cost, np.inf)))
    if straight is None:
        pts = densify(shortcut_path(tree.path_to(int(near[f])), occ), config.nu)
    else:
        pts = densify(np.vstack([current[:3], [cells[f, 0], cells[f, 1], current[2]]]), config.nu)
    # yaw: face up the gradient if known, else along the direction of travel
    if gradient is not None:
        target = np.full(len(pts), np.arctan2(gradient[1], gradient[0]))
    else:
        d = pts[-1, :2] - pts[0, :2]
        target = np.full(len(pts), np.arctan2(d[1], d[0]) if np.any(d) else current[3])
    greedy = track_yaw(pts, current[3], target, config.tree.speed, config.tree.yaw_rate_max)

    def score(points: np.ndarray, yaws: np.ndarray) -> np.ndarray:
        return np.cos(yaws - target[:, None])

    yaw = sample_yaw(pts, current[3], score, q=config.q, speed=config.tree.speed,
                     yaw_rate_max=config.tree.yaw_rate_max, rng=rng, extra=np.column_stack([target, greedy]))
    path = np.column_stack([pts, yaw])
    info["frontier"] = cells[f].tolist()
    return DwellPlan(path[-1:], path, "frontier", gains=np.array([-cost[f]]), info=info)
