"""Pure, vectorised geometry shared by the simulator, the estimators and the planner.

Walls are vertical slabs (dataset-format.md): from z = 0 to ``height``, centred on the segment
``start``-``end``, ``thickness`` thick. Path lengths are 3-D lengths of the detector-source segment
inside each slab, computed with the slab (Kay-Kajiya) method in each wall's own frame.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from radseek.dataset import Wall


def wall_arrays(walls: Sequence[Wall]) -> np.ndarray:
    """(W, 6) array of start_x, start_y, end_x, end_y, thickness, height."""
    if not walls:
        return np.zeros((0, 6))
    return np.array([[*w.start, *w.end, w.thickness, w.height] for w in walls], dtype=float)


def path_lengths_per_wall(a: np.ndarray, b: np.ndarray, walls: np.ndarray | Sequence[Wall]) -> np.ndarray:
    """Length (m) of each segment a->b inside each wall.

    a, b: (..., 3) broadcastable end points; walls: (W, 6) from ``wall_arrays`` or a list of Wall.
    Returns (..., W).
    """
    w = walls if isinstance(walls, np.ndarray) else wall_arrays(walls)
    a = np.asarray(a, dtype=float)[..., None, :]
    b = np.asarray(b, dtype=float)[..., None, :]
    if w.shape[0] == 0:
        return np.zeros(np.broadcast_shapes(a.shape, b.shape)[:-2] + (0,))
    s0, s1 = w[:, 0:2], w[:, 2:4]
    length = np.linalg.norm(s1 - s0, axis=1)
    u = (s1 - s0) / np.where(length > 0, length, 1.0)[:, None]
    v = np.stack([-u[:, 1], u[:, 0]], axis=1)
    d = b - a
    rel = a[..., :2] - s0
    # coordinates of a and of the direction d along (u, v, z)
    a_loc = np.stack([(rel * u).sum(-1), (rel * v).sum(-1), a[..., 2] * np.ones_like(rel[..., 0])], axis=-1)
    d_loc = np.stack([(d[..., :2] * u).sum(-1), (d[..., :2] * v).sum(-1), d[..., 2] * np.ones_like(rel[..., 0])],
                     axis=-1)
    lo = np.stack([np.zeros_like(length), -w[:, 4] / 2, np.zeros_like(length)], axis=-1)
    hi = np.stack([length, w[:, 4] / 2, w[:, 5]], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - a_loc) / d_loc
        t2 = (hi - a_loc) / d_loc
    parallel = d_loc == 0
    inside = (a_loc >= lo) & (a_loc <= hi)
    t_enter = np.where(parallel, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
    t_exit = np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
    enter = np.maximum(t_enter.max(-1), 0.0)
    exit_ = np.minimum(t_exit.min(-1), 1.0)
    seg = np.linalg.norm(d, axis=-1)
    # a zero-length wall has no volume: without this its in-plane axes vanish and it acts as an infinite wall
    return np.where(length > 0, np.clip(exit_ - enter, 0.0, None) * seg, 0.0)


def path_lengths(a: np.ndarray, b: np.ndarray, walls: np.ndarray | Sequence[Wall]) -> np.ndarray:
    """Total length (m) of each segment a->b inside all walls: (...,)."""
    return path_lengths_per_wall(a, b, walls).sum(-1)


def segment_hits_walls(a: np.ndarray, b: np.ndarray, walls: np.ndarray | Sequence[Wall], inflate: float = 0.0
                       ) -> np.ndarray:
    """True where segment a->b passes through any wall thickened by ``inflate`` on each side."""
    w = walls if isinstance(walls, np.ndarray) else wall_arrays(walls)
    if w.shape[0] == 0:
        return np.zeros(np.broadcast_shapes(np.shape(a), np.shape(b))[:-1], dtype=bool)
    wi = w.copy()
    if inflate:
        s0, s1 = wi[:, 0:2].copy(), wi[:, 2:4].copy()
        length = np.linalg.norm(s1 - s0, axis=1, keepdims=True)
        u = (s1 - s0) / np.where(length > 0, length, 1.0)
        wi[:, 0:2] = s0 - inflate * u
        wi[:, 2:4] = s1 + inflate * u
        wi[:, 4] += 2 * inflate
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    # a degenerate segment (a == b) still counts if the point is inside a wall
    eps = np.where(np.linalg.norm(b - a, axis=-1, keepdims=True) == 0, 1e-9, 0.0)
    return path_lengths(a, b + eps, wi) > 0


def semi_major_axis(covariance: np.ndarray) -> float:
    """Largest semi-axis (m) of the 1-sigma ellipse (ellipsoid) of a symmetric covariance (m^2): the square
    root of its largest eigenvalue, 0 for a negative one. The one formula behind every "1-sigma" in radseek
    (``estimator.inflight.sigma_m`` on the x-y block, the planner's ``SourceBelief.semi_major_axis``)."""
    return float(np.sqrt(max(np.linalg.eigvalsh(np.asarray(covariance, dtype=float)).max(), 0.0)))
