"""Baseline search patterns for side-by-side benchmarks against the eq. 6 planner.

* ``fixed_lattice``: paper 003 sec. V's nine-point lattice (3 x 3 grid around a centre);
* ``lawnmower``: boustrophedon lanes over the flight volume (paper 004 sec. 5.6's "lawn mower pattern");
* ``spiral``: Archimedean spiral from a centre, points evenly spaced by arc length (paper 004 sec. 5.6);
* ``PREGradient``: paper 001 Algorithm 1 (softmax gradient ascent, eq. 1, then e1/e2 switching around
  the threshold E, eq. 2-4, until the path closes a loop);
* ``greedy_info_gain``: paper 004 eq. 4.9-4.10, U(a) = I(a) - alpha cost(a) over the 8 neighbouring
  cells, I(a) the entropy drop of a particle cloud after the predicted observation z_hat at a.

Pattern functions return dwell points (K, 3); ``valid_points`` drops those inside grown walls.
Reactive baselines (PRE, greedy) take measured or predicted rates as plain arrays/callables and never
read the simulator. ``to_plan`` wraps a point list as a ``DwellPlan`` (straight segments: check them
with ``OccupancyMap.segments_valid`` or route them with the tree planner when walls are present).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.special import gammaln

from planner.belief import SourceBelief
from planner.occupancy import OccupancyMap
from planner.plan import DwellPlan

#: the 8 move directions of paper 001 Fig. 3(a): up, up-right, right, ... (unit vectors, x east, y north)
DIRECTIONS = np.array([[0, 1], [1, 1], [1, 0], [1, -1], [0, -1], [-1, -1], [-1, 0], [-1, 1]], dtype=float)
UNIT_DIRECTIONS = DIRECTIONS / np.linalg.norm(DIRECTIONS, axis=1, keepdims=True)


def valid_points(points: np.ndarray, occ: OccupancyMap) -> np.ndarray:
    """The points (K, 3) that are valid vehicle positions, in order."""
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    return p[occ.points_valid(p)]


def to_plan(points: np.ndarray, current: np.ndarray, method: str) -> DwellPlan:
    """Dwell points (K, 3) as a plan with yaw along travel; path = straight line to the first point."""
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    cur = np.asarray(current, dtype=float).reshape(4)
    prev = np.vstack([cur[None, :3], p])
    d = np.diff(prev, axis=0)
    yaw = np.where(np.any(d[:, :2] != 0, axis=1), np.arctan2(d[:, 1], d[:, 0]), cur[3])
    dwell = np.column_stack([p, yaw])
    path = np.vstack([cur, dwell[:1]]) if len(p) else np.zeros((0, 4))
    return DwellPlan(dwell, path, method)


def fixed_lattice(center: np.ndarray, spacing: float = 1.0, z: float | None = None) -> np.ndarray:
    """Nine dwell points (9, 3): a 3 x 3 lattice of ``spacing`` (m) around ``center``, boustrophedon order."""
    c = np.asarray(center, dtype=float).reshape(3)
    zz = c[2] if z is None else z
    pts = []
    for row, dy in enumerate((-1, 0, 1)):
        for dx in (-1, 0, 1) if row % 2 == 0 else (1, 0, -1):
            pts.append([c[0] + dx * spacing, c[1] + dy * spacing, zz])
    return np.array(pts)


def lawnmower(bounds_min: np.ndarray, bounds_max: np.ndarray, spacing: float, z: float, margin: float = 0.5
              ) -> np.ndarray:
    """Dwell points on lanes along x, ``spacing`` apart in y and along each lane, alternating direction."""
    lo = np.asarray(bounds_min, dtype=float)[:2] + margin
    hi = np.asarray(bounds_max, dtype=float)[:2] - margin
    xs = np.arange(lo[0], hi[0] + 1e-9, spacing)
    ys = np.arange(lo[1], hi[1] + 1e-9, spacing)
    pts = [[x, y, z] for k, y in enumerate(ys) for x in (xs if k % 2 == 0 else xs[::-1])]
    return np.array(pts).reshape(-1, 3)


def spiral(center: np.ndarray, spacing: float, bounds_min: np.ndarray, bounds_max: np.ndarray,
           max_points: int = 200) -> np.ndarray:
    """Archimedean spiral r = spacing * theta / (2 pi) from ``center``: points ``spacing`` apart by arc
    length, turns ``spacing`` apart, stopped when a whole turn lies outside the bounds (K, 3)."""
    c = np.asarray(center, dtype=float).reshape(3)
    lo, hi = np.asarray(bounds_min, dtype=float), np.asarray(bounds_max, dtype=float)
    b = spacing / (2 * np.pi)
    pts = [c.copy()]
    theta, outside_run = 0.0, 0.0
    while len(pts) < max_points:
        r = b * theta
        theta += spacing / max(np.hypot(r, b), 1e-9)  # ds = sqrt(r^2 + b^2) dtheta
        r = b * theta
        p = np.array([c[0] + r * np.cos(theta), c[1] + r * np.sin(theta), c[2]])
        if np.all(p[:2] >= lo[:2]) and np.all(p[:2] <= hi[:2]):
            pts.append(p)
            outside_run = 0.0
        else:
            outside_run += spacing
            if outside_run > 2 * np.pi * r:
                break
    return np.array(pts)


@dataclass
class PREGradient:
    """Paper 001 Algorithm 1 as a stateful policy: call ``step`` once per measurement.

    threshold: E (cps) switching from gradient ascent to circling; step: s (m); q: softmax temperature.
    """

    threshold: float
    step: float = 1.0
    q: float = 1.0
    rid_flag: bool = True  # Algorithm 1's RID FLAG: True while approaching

    def step_from(self, position: np.ndarray, rate: float, neighbour_rates: np.ndarray,
                  rng: np.random.Generator) -> np.ndarray:
        """Next position (3,) from the current ``position`` (3,), its reading y_i and the readings
        (8,) one step away along ``DIRECTIONS`` (eq. 1-4: g_k = (r_k - y_i) / dl_k)."""
        pos = np.asarray(position, dtype=float)
        g = (np.asarray(neighbour_rates, dtype=float) - rate) / self.step
        e1 = UNIT_DIRECTIONS[int(np.argmax(g))]
        if self.rid_flag:
            z = g / self.q
            prob = np.exp(z - z.max())
            prob /= prob.sum()  # eq. 1 softmax
            e = UNIT_DIRECTIONS[int(rng.choice(8, p=prob))]
            if rate >= self.threshold:
                self.rid_flag = False
        else:
            e = e1 if rate < self.threshold else np.array([e1[1], -e1[0]])  # eq. 4; e2 clockwise of e1
        return pos + self.step * np.r_[e, 0.0]  # eq. 3


def path_closed(points: np.ndarray) -> bool:
    """Paper 001's stop rule: the newest segment crosses an earlier, non-adjacent segment (x, y)."""
    p = np.asarray(points, dtype=float)[:, :2]
    if len(p) < 4:
        return False
    a, b = p[-2], p[-1]

    def cross(o, u, v):
        return (u[0] - o[0]) * (v[1] - o[1]) - (u[1] - o[1]) * (v[0] - o[0])

    for i in range(len(p) - 3):
        c, d = p[i], p[i + 1]
        d1, d2 = cross(c, d, a), cross(c, d, b)
        d3, d4 = cross(a, b, c), cross(a, b, d)
        if d1 * d2 <= 0 and d3 * d4 <= 0 and (d1, d2, d3, d4) != (0, 0, 0, 0):
            return True
    return False


def run_pre(start: np.ndarray, rate_at: Callable[[np.ndarray], np.ndarray], policy: PREGradient,
            rng: np.random.Generator, occ: OccupancyMap | None = None, max_points: int = 60) -> np.ndarray:
    """Roll Algorithm 1 out with a rate callback (points (n, 3) -> rates (n,)): the benchmark hook.

    Moves into walls or out of bounds are replaced by the next most probable valid move. Returns the
    visited dwell points (K, 3) including ``start``, stopping when the circling path closes a loop.
    """
    pts = [np.asarray(start, dtype=float)]
    while len(pts) < max_points:
        here = pts[-1]
        nbrs = here + policy.step * np.c_[UNIT_DIRECTIONS, np.zeros(8)]
        rates = np.asarray(rate_at(np.vstack([here, nbrs])), dtype=float)
        nxt = policy.step_from(here, rates[0], rates[1:], rng)
        if occ is not None and not occ.segment_valid(here, nxt):
            ok = occ.segments_valid(np.broadcast_to(here, nbrs.shape), nbrs)
            if not ok.any():
                break
            nxt = nbrs[ok][int(np.argmax(rates[1:][ok]))]
        pts.append(nxt)
        # the loop-closure stop only applies once circling (a random-walk approach may cross itself)
        if not policy.rid_flag and path_closed(np.array(pts)):
            break
    return np.array(pts)


def particle_entropy(weights: np.ndarray) -> np.ndarray:
    """H = -sum w log w over the last axis (paper 004 eq. 4.5), weights normalised first."""
    w = np.asarray(weights, dtype=float)
    w = w / w.sum(-1, keepdims=True)
    return -(np.where(w > 0, w * np.log(np.where(w > 0, w, 1.0)), 0.0)).sum(-1)


def greedy_info_gain(position: np.ndarray, belief: SourceBelief, occ: OccupancyMap, *, step: float = 1.0,
                     dwell_s: float = 5.0, alpha: float = 0.05, n_particles: int = 500,
                     rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Paper 004 eq. 4.9-4.10 over the 8 neighbours one ``step`` away: returns (best point (3,), U (8,)).

    Particles are drawn from the Gaussian belief (equal weights); the predicted observation at action a
    is z_hat = (cps_at_1m / r^2 + b) * dwell_s from the belief mean (paper 004: "calculated by eq. 2.2
    using the estimated intensity"); I(a) = H(w) - H(w * Poisson(z_hat | mu_i(a))), cost(a) = step
    length. Invalid neighbours (walls, bounds, blocked moves) get U = -inf.
    """
    rng = rng if rng is not None else np.random.default_rng()
    pos = np.asarray(position, dtype=float).reshape(3)
    cand = pos + step * np.c_[UNIT_DIRECTIONS, np.zeros(8)]
    parts = rng.multivariate_normal(belief.mean, belief.covariance, n_particles)  # (P, 3)
    w0 = np.full(n_particles, 1.0 / n_particles)
    r2 = np.maximum(((cand[:, None, :] - parts[None]) ** 2).sum(-1), 0.05**2)  # (8, P)
    mu = (belief.cps_at_1m / r2 + belief.background_cps) * dwell_s
    z_hat = np.round(belief.predicted_net_rate(cand) * dwell_s + belief.background_cps * dwell_s)  # (8,)
    loglik = z_hat[:, None] * np.log(mu) - mu - gammaln(z_hat[:, None] + 1)
    w1 = w0 * np.exp(loglik - loglik.max(1, keepdims=True))
    info = particle_entropy(w0) - particle_entropy(w1)  # eq. 4.9
    utility = info - alpha * step  # eq. 4.10
    ok = occ.segments_valid(np.broadcast_to(pos, cand.shape), cand)
    utility = np.where(ok, utility, -np.inf)
    return cand[int(np.argmax(utility))], utility
