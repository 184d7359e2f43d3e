"""Flight paths of the independent forward model: waypoints with dwells, flown in straight lines at constant speed.

A path is a list of legs; each leg flies from the previous point to ``point`` at ``speed`` (transit frames,
dwell -1) and then hovers ``dwell_s`` there (dwell index i), turning ``turns`` full turns while hovering.
While moving, the detector axis points along the motion; while hovering it keeps a random heading (or spins).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Leg:
    point: tuple[float, float, float]
    dwell_s: float = 0.0
    turns: float = 0.0


class Track:
    """A flight as knots: at time ``times[k]`` the vehicle is at ``points[k]``, and from one knot to the next it
    flies a straight line at constant speed (or hovers, both knots at one place). Piece k (knot k to k + 1) has
    a dwell index ``dwell[k]`` (-1 moving) and the yaw ``yaw0[k] + yaw_rate[k] * (t - times[k])``.

    Built from ``legs`` all at once: every leg is a transit from the previous point (kept when longer than 1 um)
    followed by a hover (kept when ``dwell_s`` > 0); these candidate pieces form a (legs, 2) grid, and the
    kept ones, in leg order, are the track. Each hover draws a random heading from ``rng``, in order.
    """

    def __init__(self, start: tuple[float, float, float], legs: list[Leg], rng: np.random.Generator,
                 speed: float = 1.0):
        pts = np.array([start, *(leg.point for leg in legs)], dtype=float)
        step = np.diff(pts, axis=0)
        length = np.linalg.norm(step, axis=1)
        dwell_s = np.array([leg.dwell_s for leg in legs], dtype=float)
        hover = dwell_s > 0
        keep = np.column_stack([length > 1e-6, hover]).ravel()

        def pieces(transit: np.ndarray, hovering: np.ndarray) -> np.ndarray:
            return np.column_stack([transit, hovering]).ravel()[keep]

        heading = np.where(np.hypot(step[:, 0], step[:, 1]) > 1e-6, np.arctan2(step[:, 1], step[:, 0]), 0.0)
        hover_yaw = np.zeros(len(legs))
        hover_yaw[hover] = rng.uniform(-np.pi, np.pi, int(hover.sum()))
        turns = np.array([leg.turns for leg in legs], dtype=float)
        spin = np.divide(2 * np.pi * turns, dwell_s, out=np.zeros(len(legs)), where=hover)
        self.times = np.r_[0.0, np.cumsum(pieces(length / speed, dwell_s))]
        self.points = np.vstack([pts[:1], np.repeat(pts[1:], 2, axis=0)[keep]])
        self.dwell = pieces(np.full(len(legs), -1), np.cumsum(hover) - 1)
        self.yaw0 = pieces(heading, hover_yaw)
        self.yaw_rate = pieces(np.zeros(len(legs)), spin)

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def sample(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(positions (N, 3), yaw (N,), dwell (N,), piece index (N,)) at times t."""
        i = np.clip(np.searchsorted(self.times[1:], t, side="left"), 0, len(self.dwell) - 1)
        t0, t1 = self.times[i], self.times[i + 1]
        f = np.clip((t - t0) / np.maximum(t1 - t0, 1e-9), 0.0, 1.0)[:, None]
        pos = self.points[i] + f * (self.points[i + 1] - self.points[i])
        yaw = self.yaw0[i] + self.yaw_rate[i] * (t - t0)
        return pos, (yaw + np.pi) % (2 * np.pi) - np.pi, self.dwell[i], i


def ring_points(c: np.ndarray, rng: np.random.Generator, n: int, r_lo: float, r_hi: float) -> list[tuple[float, float]]:
    ang = rng.uniform(0, 2 * np.pi) + np.arange(n) * 2 * np.pi / n + rng.normal(0, 0.2, n)
    r = rng.uniform(r_lo, r_hi, n)
    return [(float(c[0] + ri * np.cos(a)), float(c[1] + ri * np.sin(a))) for ri, a in zip(r, ang, strict=True)]


def lattice(src: np.ndarray, far: tuple[float, float], rng: np.random.Generator, n: int = 8, alt: float = 1.3,
            dwell_s: float = 8.0, r: tuple[float, float] = (1.0, 3.5), turns: float = 0.0) -> Track:
    """One far (background) dwell, then ``n`` dwells around the source in a ring, then home."""
    pts = ring_points(src, rng, n, *r)
    legs = [Leg((far[0], far[1], alt), dwell_s, turns)]
    legs += [Leg((x, y, alt + rng.uniform(-0.2, 0.2)), dwell_s * rng.uniform(0.8, 1.25), turns) for x, y in pts]
    return Track((far[0], far[1], alt), legs, rng)


def lawnmower(lo: tuple[float, float], hi: tuple[float, float], rng: np.random.Generator, spacing: float = 1.5,
              alt: float = 1.5, speed: float = 1.0, end_dwells: list[tuple[float, float]] | None = None,
              dwell_s: float = 10.0) -> Track:
    """Lines along x at ``spacing`` in y, alternating direction; optional background dwells before and after."""
    ys = np.arange(lo[1], hi[1] + 1e-9, spacing)
    legs: list[Leg] = []
    ends = end_dwells or []
    if ends:
        legs.append(Leg((ends[0][0], ends[0][1], alt), dwell_s))
    for j, y in enumerate(ys):
        xa, xb = (lo[0], hi[0]) if j % 2 == 0 else (hi[0], lo[0])
        legs += [Leg((xa, float(y), alt)), Leg((xb, float(y), alt))]
    if len(ends) > 1:
        legs.append(Leg((ends[1][0], ends[1][1], alt), dwell_s))
    start = (ends[0][0], ends[0][1], alt) if ends else (lo[0], float(ys[0]), alt)
    return Track(start, legs, rng, speed)


def close_pass(src: np.ndarray, rng: np.random.Generator, alt: float = 1.0, dwell_s: float = 6.0) -> Track:
    """Dwells at 1-6 m horizontal distance from the source and low passes straight over it."""
    a = rng.uniform(0, 2 * np.pi)
    legs = []
    for k, d in enumerate((6.0, 4.0, 3.0, 2.0, 1.3, 0.8)):
        ang = a + k * 2.1
        legs.append(Leg((float(src[0] + d * np.cos(ang)), float(src[1] + d * np.sin(ang)), alt), dwell_s))
        legs.append(Leg((float(src[0] - d * np.cos(ang)), float(src[1] - d * np.sin(ang)), alt * 0.8)))
    legs.append(Leg((float(src[0] + 6.0), float(src[1]), alt), dwell_s))
    start = (float(src[0] + 7.0), float(src[1] + 1.0), alt)
    return Track(start, legs, rng, speed=1.0)
