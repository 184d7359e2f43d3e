"""Yaw along a path: nu samples, q random yaw candidates each, best feasible sequence (paper 003 IV-B-3).

"This path is sampled at nu points and a set of q yaw angle orientations are randomly sampled at each
new vertex. Subject to the maximum yaw rate psi_dot_max, the method then identifies the sequence of yaw
angle orientations that [maximizes the exploration gain of its ref. 28]."

We keep the structure and swap the objective (radseek has no volumetric exploration gain): each
candidate scores by ``score(points, yaws)``, by default the alignment cos(psi - bearing to the source
estimate) of the detector axis (body +x), which maximises counts and keeps the source out of the rear
low-sensitivity cone. Dynamic programming (Viterbi) over the nu x q lattice finds the sequence of
largest total score whose every step obeys |dpsi| <= psi_dot_max * ds / v_t. Holding the start yaw is
always one of the candidates, so a feasible sequence always exists.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from planner.dwell_tree import wrap_angle

ScoreFn = Callable[[np.ndarray, np.ndarray], np.ndarray]  # points (nu, 3), yaws (nu, q) -> (nu, q)


def bearings(points: np.ndarray, source: np.ndarray) -> np.ndarray:
    """(nu,) yaw that points the detector axis from each point towards ``source`` (horizontal)."""
    return np.arctan2(source[1] - points[:, 1], source[0] - points[:, 0])


def track_yaw(points: np.ndarray, start_yaw: float, targets: np.ndarray, speed: float, yaw_rate_max: float
              ) -> np.ndarray:
    """Greedy feasible yaw (nu,): turn towards ``targets`` (nu,) as fast as the yaw-rate limit allows."""
    allow = yaw_rate_max * np.linalg.norm(np.diff(points, axis=0), axis=1) / speed
    out = np.empty(len(points))
    out[0] = start_yaw
    for k in range(1, len(points)):
        step = np.clip(wrap_angle(targets[k] - out[k - 1]), -allow[k - 1], allow[k - 1])
        out[k] = wrap_angle(out[k - 1] + step)
    return out


def bearing_score(source: np.ndarray) -> ScoreFn:
    """Score cos(psi - bearing from each point to ``source``): 1 when the detector axis faces it."""
    src = np.asarray(source, dtype=float)

    def score(points: np.ndarray, yaws: np.ndarray) -> np.ndarray:
        bearing = np.arctan2(src[1] - points[:, 1], src[0] - points[:, 0])
        return np.cos(yaws - bearing[:, None])

    return score


def sample_yaw(points: np.ndarray, start_yaw: float, score: ScoreFn, *, q: int = 8, speed: float = 0.5,
               yaw_rate_max: float = 0.5, rng: np.random.Generator | None = None,
               extra: np.ndarray | None = None) -> np.ndarray:
    """Yaw (nu,) at points (nu, 3) starting at ``start_yaw`` (fixed at point 0), best feasible sequence.

    ``extra`` (nu, e) adds deterministic candidates (e.g. the bearing to the source) to the random ones.
    Feasible: |wrap(psi_{k+1} - psi_k)| <= yaw_rate_max * |p_{k+1} - p_k| / speed at every step.
    """
    rng = rng if rng is not None else np.random.default_rng()
    pts = np.asarray(points, dtype=float)
    nu = len(pts)
    # candidates: column 0 holds the start yaw (always feasible), then q random angles per vertex
    parts = [np.full((nu, 1), start_yaw), rng.uniform(-np.pi, np.pi, (nu, q))]
    if extra is not None:
        parts.append(np.asarray(extra, dtype=float).reshape(nu, -1))
    cand = np.concatenate(parts, axis=1)
    q = cand.shape[1] - 1
    cand[0, :] = start_yaw
    cand = np.asarray(wrap_angle(cand))
    s = np.asarray(score(pts, cand), dtype=float)
    allow = yaw_rate_max * np.linalg.norm(np.diff(pts, axis=0), axis=1) / speed  # (nu-1,)
    best = np.where(np.arange(q + 1) == 0, s[0], -np.inf)
    back = np.zeros((nu, q + 1), dtype=int)
    for k in range(1, nu):
        step = np.abs(np.asarray(wrap_angle(cand[k][None, :] - cand[k - 1][:, None])))  # (from, to)
        total = np.where(step <= allow[k - 1] + 1e-9, best[:, None], -np.inf)
        back[k] = np.argmax(total, axis=0)
        best = total[back[k], np.arange(q + 1)] + s[k]
    j = int(np.argmax(best))
    out = np.empty(nu)
    for k in range(nu - 1, -1, -1):
        out[k] = cand[k, j]
        j = back[k, j]
    return out
