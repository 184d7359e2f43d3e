"""Random tree of configurations xi = [x, y, z, psi] grown with OMPL's RRT (paper 003 sec. IV-B-3).

"The planner starts from the current robot configuration xi_0 and incrementally builds a geometric
random tree T with maximum edge length l ... A minimum of N_min and maximum of N_max nodes ... yaw rate
constraints psi_dot_max are respected given a constant linear velocity v_t."

The state space is OMPL's compound R^3 (bounded by the flight volume shrunk by the vehicle radius) x SO(2).
The tree has no goal: an unreachable goal state, goal bias 0 and a termination condition that counts
accepted edges stop it at N_max nodes (or at the soft time budget once it has N_min, or at a hard limit).
Edges are accepted by a Python motion validator that checks, exactly and without sampling,

* the segment clears every wall grown by the vehicle radius (``OccupancyMap.segment_valid``), and
* the yaw change fits the yaw-rate limit at speed v_t: |dpsi| <= psi_dot_max * |dp| / v_t.

``Tree`` is the read-back (states and parent indices) as numpy arrays; ``Tree.path_to`` extracts the
collision-free path mu_0 from the root to a node.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from planner.occupancy import OccupancyMap

ou.setLogLevel(ou.LogLevel.LOG_WARN)

def seed_ompl(seed: int) -> None:
    """Restart OMPL's seed sequence at ``seed``: every random generator created after this (each tree's
    sampler) follows it, so a flight is the same whatever was planned before it in the process.

    OMPL logs an error when the sequence is restarted after generators exist (generators made before keep
    their state); the restart itself works (checked in tests/test_dwell_tree.py), and each ``grow_tree``
    makes fresh generators, so the message is silenced here."""
    level = ou.getLogLevel()
    ou.setLogLevel(ou.LogLevel.LOG_NONE)
    try:
        ou.RNG.setSeed(int(seed))
    finally:
        ou.setLogLevel(level)


@dataclass(frozen=True)
class TreeConfig:
    """Tree settings (paper 003 sec. IV-B-3 symbols in brackets)."""

    max_edge: float = 1.0  # m, > 0 [l]: OMPL RRT range (edge length in position)
    n_min: int = 100  # [N_min], >= 2
    n_max: int = 500  # [N_max], >= n_min
    speed: float = 0.5  # m/s, > 0 [v_t]
    yaw_rate_max: float = 0.5  # rad/s, > 0 [psi_dot_max]
    yaw_weight: float = 0.1  # m per rad, > 0: weight of yaw in OMPL's state distance
    time_budget: float = 0.2  # s: stop at N_min or more nodes once this has passed
    time_limit: float = 2.0  # s: stop whatever the node count
    steer_yaw: bool = True  # clamp an edge's yaw change to the limit instead of rejecting the edge

    def __post_init__(self) -> None:
        if self.max_edge <= 0 or self.speed <= 0 or self.yaw_rate_max <= 0 or self.yaw_weight <= 0:
            raise ValueError("max_edge, speed, yaw_rate_max and yaw_weight must be > 0")
        if not (2 <= self.n_min <= self.n_max):
            raise ValueError("need 2 <= n_min <= n_max")

    @property
    def yaw_per_metre(self) -> float:
        """rad/m: largest yaw change per metre flown at v_t."""
        return self.yaw_rate_max / self.speed


@dataclass(frozen=True)
class Tree:
    """A grown tree: states (N, 4) [x, y, z, psi] and parent indices (N,), -1 at the root (index 0)."""

    states: np.ndarray
    parent: np.ndarray
    build_time: float  # s, wall time spent growing (for benchmarks)
    motions_checked: int

    def __len__(self) -> int:
        return len(self.states)

    def path_to(self, i: int) -> np.ndarray:
        """(k, 4) states from the root to node i along tree edges."""
        idx = []
        while i >= 0:
            idx.append(i)
            i = int(self.parent[i])
        return self.states[idx[::-1]]

    def path_lengths(self) -> np.ndarray:
        """(N,) metres (position only) from the root to every node along tree edges; vectorised by
        pointer jumping (log2(depth) numpy steps)."""
        parent = np.asarray(self.parent, dtype=int)
        pos = self.states[:, :3]
        acc = np.where(parent >= 0, np.linalg.norm(pos - pos[np.maximum(parent, 0)], axis=1), 0.0)
        anc = parent.copy()
        while (anc >= 0).any():
            up = anc >= 0
            acc = acc + np.where(up, acc[np.maximum(anc, 0)], 0.0)
            anc = np.where(up, anc[np.maximum(anc, 0)], -1)
        return acc

    def edges(self) -> tuple[np.ndarray, np.ndarray]:
        """(E, 4) parent states and (E, 4) child states of every edge."""
        child = np.flatnonzero(self.parent >= 0)
        return self.states[self.parent[child]], self.states[child]


def wrap_angle(a: np.ndarray | float) -> np.ndarray | float:
    """Angle(s) wrapped to [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


class _EdgeValidator(ob.MotionValidator):
    """Exact wall clearance plus the yaw-rate limit, counting accepted edges for termination."""

    def __init__(self, si: ob.SpaceInformation, occ: OccupancyMap, yaw_per_metre: float, steer_yaw: bool):
        super().__init__(si)
        self.steer_yaw = steer_yaw
        self.occ = occ
        self.yaw_per_metre = yaw_per_metre
        self.checked = 0
        self.accepted = 0

    def checkMotion(self, a, b) -> bool:  # noqa: N802 (OMPL's name)
        self.checked += 1
        pa, pb = a[0], b[0]
        p = (pa[0], pa[1], pa[2])
        q = (pb[0], pb[1], pb[2])
        length = math.dist(p, q)
        dpsi = math.remainder(b[1].value - a[1].value, 2 * math.pi)
        limit = self.yaw_per_metre * length
        if abs(dpsi) > limit:
            if not self.steer_yaw:
                return False
            # steer: RRT copies the checked state into the tree, so clamping its yaw here adds the
            # closest yaw-feasible state instead of wasting the sample (checked in the tests)
            b[1].value = math.remainder(a[1].value + math.copysign(limit, dpsi), 2 * math.pi)
        if not self.occ.segment_valid(p, q):
            return False
        self.accepted += 1
        return True


def _space(occ: OccupancyMap, yaw_weight: float) -> ob.CompoundStateSpace:
    r3 = ob.RealVectorStateSpace(3)
    bounds = ob.RealVectorBounds(3)
    lo, hi = occ.free_min, occ.free_max
    for k in range(3):
        # OMPL needs a non-empty interval; a flat volume (z fixed) gets a 1 mm slab
        bounds.setLow(k, float(lo[k]))
        bounds.setHigh(k, float(max(hi[k], lo[k] + 1e-3)))
    r3.setBounds(bounds)
    space = ob.CompoundStateSpace()
    space.addSubspace(r3, 1.0)
    space.addSubspace(ob.SO2StateSpace(), yaw_weight)
    return space


def grow_tree(start: np.ndarray, occ: OccupancyMap, config: TreeConfig = TreeConfig()) -> Tree:
    """Grow an RRT from ``start`` = (x, y, z, psi) in the free space of ``occ``; read it back as arrays.

    Raises ValueError if the start configuration is not valid (inside a grown wall or out of bounds).
    """
    start = np.asarray(start, dtype=float).reshape(4)
    if not occ.point_valid(*start[:3]):
        raise ValueError(f"start position {start[:3]} is inside a wall or outside the flight volume")
    space = _space(occ, config.yaw_weight)
    si = ob.SpaceInformation(space)

    def state_valid(s) -> bool:
        p = s[0]
        return occ.point_valid(p[0], p[1], p[2])

    si.setStateValidityChecker(state_valid)
    validator = _EdgeValidator(si, occ, config.yaw_per_metre, config.steer_yaw)
    si.setMotionValidator(validator)
    # not used by RRT (edges go through the exact validator) but kept fine for any other OMPL use
    si.setStateValidityCheckingResolution(min(0.01, max(occ.radius, 0.05) / max(si.getMaximumExtent(), 1e-9)))
    si.setup()

    s0 = si.allocState()
    for k in range(3):
        s0[0][k] = float(start[k])
    s0[1].value = float(wrap_angle(start[3]))
    goal = si.allocState()  # any state: with threshold 1e-9 it is never reached
    for k in range(3):
        goal[0][k] = float(occ.free_max[k])
    goal[1].value = math.pi - 1e-6
    pdef = ob.ProblemDefinition(si)
    pdef.addStartState(s0)
    pdef.setGoalState(goal, 1e-9)

    planner = og.RRT(si)
    planner.setRange(config.max_edge)
    planner.setGoalBias(0.0)
    planner.setProblemDefinition(pdef)
    planner.setup()

    t0 = time.perf_counter()

    def stop() -> bool:
        nodes = validator.accepted + 1
        if nodes >= config.n_max:
            return True
        dt = time.perf_counter() - t0
        return dt >= config.time_limit or (dt >= config.time_budget and nodes >= config.n_min)

    planner.solve(ob.PlannerTerminationCondition(stop))
    pd = ob.PlannerData(si)
    planner.getPlannerData(pd)
    n = pd.numVertices()
    states = np.empty((n, 4))
    parent = np.full(n, -1, dtype=int)
    for i in range(n):
        s = pd.getVertex(i).getState()
        p = s[0]
        states[i] = (p[0], p[1], p[2], s[1].value)
        incoming = pd.getIncomingEdges(i)
        if incoming:
            parent[i] = incoming[0]
    build_time = time.perf_counter() - t0
    root = int(pd.getStartIndex(0)) if pd.numStartVertices() else 0
    if root != 0:  # re-index so the root is node 0
        order = np.r_[root, np.delete(np.arange(n), root)]
        inv = np.empty(n, dtype=int)
        inv[order] = np.arange(n)
        states = states[order]
        parent = np.where(parent[order] >= 0, inv[np.maximum(parent[order], 0)], -1)
    return Tree(states=states, parent=parent, build_time=build_time, motions_checked=validator.checked)


def shortcut_path(path: np.ndarray, occ: OccupancyMap) -> np.ndarray:
    """Greedy shortcutting of a valid polyline (k, >=3): from each kept vertex jump to the farthest
    later vertex whose straight segment is valid. Returns positions (m, 3), m <= k, still valid."""
    p = np.asarray(path, dtype=float)[:, :3]
    out = [0]
    i = 0
    while i < len(p) - 1:
        j = len(p) - 1
        while j > i + 1 and not occ.segment_valid(p[i], p[j]):
            j -= 1
        out.append(j)
        i = j
    return p[out]


def densify(path: np.ndarray, nu: int) -> np.ndarray:
    """The polyline's vertices plus nu arc-length-even samples, in order (so no chord cuts a corner)."""
    p = np.asarray(path, dtype=float)[:, :3]
    if len(p) < 2:
        return p.copy()
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    s = np.r_[0.0, np.cumsum(seg)]
    si = np.unique(np.r_[s, np.linspace(0.0, s[-1], max(nu, 2))])
    return np.stack([np.interp(si, s, p[:, k]) for k in range(3)], axis=-1)
