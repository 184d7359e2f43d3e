"""Deconfliction of several vehicles' dwell points and paths (paper 004's multi-robot search), pure geometry.

Each vehicle of a team *reserves* the airspace it has committed to: the polyline from where it was when it
planned to its dwell point (its remaining path), then the dwell point itself, where it stays until it plans
again. A dwelling or holding vehicle reserves one point. A vehicle may take a plan only if every point
of its path, dwell point included, keeps ``separation`` (horizontal, m) from every teammate's reservation:

* no two vehicles at one dwell point, and none within ``separation`` of another's (the path's end);
* the minimum separation in the air holds at every time: each vehicle is always on its own reservation
  (it flies its path, then stays at its end), and reservations are kept apart when they are made;
* so no two paths cross while both are flown (a stronger rule than "not at the same time": it needs no
  shared clock, so it holds between processes whose simulated clocks run apart).

Paths are checked as continuous segments (point-to-segment distances of a densified path against the
reservation's segments), vectorised over all pairs.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

#: m between the samples of a path checked against the reservations (well below any separation used)
SAMPLE_STEP_M = 0.05
#: the drift margin in sigmas: the x-y distance between two vehicles' true positions differs from the distance
#: between their estimates by the difference of their drifts, per axis N(0, var_a + var_b); its norm exceeds
#: k sqrt(var_a + var_b) with probability exp(-k^2 / 2) (1.1 % at k = 3)
DRIFT_K = 3.0


@dataclass(frozen=True)
class Reservation:
    """A teammate's reservation: the polyline (k, 3) and the x-y pose variance (m^2 per axis) its odometry
    reports at the reservation's end (its drift by then: the margin the separation needs on true positions)."""

    path: np.ndarray
    var_xy: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", np.asarray(self.path, dtype=float).reshape(-1, 3))
        if not (np.isfinite(self.var_xy) and self.var_xy >= 0):
            raise ValueError("var_xy must be finite and >= 0")


def as_reservation(r: np.ndarray | Reservation) -> Reservation:
    return r if isinstance(r, Reservation) else Reservation(np.asarray(r, dtype=float))


def required_clearance(separation: float, var_a: float, var_b: float, k: float = DRIFT_K) -> float:
    """m between two estimated positions so that the true ones keep ``separation`` (:data:`DRIFT_K`)."""
    return separation + k * float(np.sqrt(max(var_a, 0.0) + max(var_b, 0.0)))


def sample_polyline(path: np.ndarray, step: float = SAMPLE_STEP_M) -> np.ndarray:
    """(P, 2) x-y points along a polyline (k, >=2) every ``step`` m, vertices included."""
    p = np.asarray(path, dtype=float).reshape(len(path), -1)[:, :2]
    if len(p) < 2:
        return p.copy()
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    s = np.r_[0.0, np.cumsum(seg)]
    si = np.unique(np.r_[s, np.arange(0.0, s[-1], step)])
    return np.column_stack([np.interp(si, s, p[:, 0]), np.interp(si, s, p[:, 1])])


def point_segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(P, S) x-y distance of points (P, >=2) to segments a-b (S, >=2); a == b is a point."""
    p = np.asarray(points, dtype=float)[:, None, :2]
    a = np.asarray(a, dtype=float)[None, :, :2]
    b = np.asarray(b, dtype=float)[None, :, :2]
    ab = b - a
    den = (ab**2).sum(-1)
    u = np.clip(((p - a) * ab).sum(-1) / np.where(den > 0, den, 1.0), 0.0, 1.0)
    return np.linalg.norm(p - (a + u[..., None] * ab), axis=-1)


def _segments(reservation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r = np.asarray(reservation, dtype=float).reshape(-1, np.shape(reservation)[-1])[:, :2]
    if len(r) == 1:
        return r, r
    return r[:-1], r[1:]


def clearance(points: np.ndarray, reservations: Iterable[np.ndarray | Reservation]) -> np.ndarray:
    """(P,) smallest x-y distance of each point (P, >=2) to any reservation (polylines (k, >=2), k >= 1);
    inf without reservations."""
    pts = np.asarray(points, dtype=float).reshape(-1, np.shape(points)[-1] if np.ndim(points) > 1 else 2)
    out = np.full(len(pts), np.inf)
    for r in reservations:
        r = as_reservation(r).path
        if len(r) == 0:
            continue
        a, b = _segments(r)
        out = np.minimum(out, point_segment_distance(pts, a, b).min(axis=1))
    return out


def path_clear(path: np.ndarray, reservations: Sequence[np.ndarray | Reservation], separation: float,
               var_xy: float = 0.0, k: float = DRIFT_K) -> bool:
    """Does the whole path (k, >=2), end included, keep ``separation`` m from every reservation, widened by the
    drift margin of both vehicles (``var_xy``: this vehicle's x-y pose variance at the path's end)?"""
    if not len(reservations):
        return True
    pts = sample_polyline(path)
    return all(clearance(pts, [r]).min() >= required_clearance(separation, var_xy, r.var_xy, k)
               for r in map(as_reservation, reservations))


def reservation(path: np.ndarray | None, position: np.ndarray) -> np.ndarray:
    """A vehicle's reservation (k, 3): the rest of its path from ``position`` when it flies one (the path's
    vertices after the nearest point to ``position``), else the point ``position``."""
    pos = np.asarray(position, dtype=float).reshape(-1)[:3]
    if path is None or len(path) < 2:
        return pos[None, :]
    p = np.asarray(path, dtype=float)[:, :3]
    d = point_segment_distance(pos[None, :], p[:-1], p[1:])[0]
    k = int(np.argmin(d))  # the segment the vehicle is on
    return np.vstack([pos, p[k + 1:]])


def pairwise_min_distance(positions: np.ndarray) -> float:
    """Smallest x-y distance between any two of positions (V, >=2); inf for fewer than two."""
    p = np.asarray(positions, dtype=float)[:, :2]
    if len(p) < 2:
        return float("inf")
    d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=-1)
    return float(d[np.triu_indices(len(p), 1)].min())


__all__ = ["DRIFT_K", "Reservation", "as_reservation", "clearance", "pairwise_min_distance", "path_clear",
           "point_segment_distance", "required_clearance", "reservation", "sample_polyline"]
