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


@dataclass
class Track:
    """Piecewise pieces: start/end time and position, dwell index (-1 transit), yaw at start and yaw rate."""

    t0: np.ndarray
    t1: np.ndarray
    p0: np.ndarray
    p1: np.ndarray
    dwell: np.ndarray
    yaw0: np.ndarray
    yaw_rate: np.ndarray

    @property
    def duration(self) -> float:
        return float(self.t1[-1])

    def sample(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(positions (N, 3), yaw (N,), dwell (N,), piece index (N,)) at times t."""
        i = np.clip(np.searchsorted(self.t1, t, side="left"), 0, len(self.t1) - 1)
        span = np.maximum(self.t1[i] - self.t0[i], 1e-9)
        f = np.clip((t - self.t0[i]) / span, 0.0, 1.0)[:, None]
        pos = self.p0[i] + f * (self.p1[i] - self.p0[i])
        yaw = self.yaw0[i] + self.yaw_rate[i] * (t - self.t0[i])
        return pos, (yaw + np.pi) % (2 * np.pi) - np.pi, self.dwell[i], i


def fly(start: tuple[float, float, float], legs: list[Leg], rng: np.random.Generator, speed: float = 1.0) -> Track:
    rows = []
    t = 0.0
    p = np.asarray(start, dtype=float)
    k = 0
    for leg in legs:
        q = np.asarray(leg.point, dtype=float)
        dist = float(np.linalg.norm(q - p))
        if dist > 1e-6:
            head = float(np.arctan2(q[1] - p[1], q[0] - p[0])) if np.hypot(*(q - p)[:2]) > 1e-6 else 0.0
            rows.append((t, t + dist / speed, p, q, -1, head, 0.0))
            t += dist / speed
        if leg.dwell_s > 0:
            rows.append((t, t + leg.dwell_s, q, q, k, rng.uniform(-np.pi, np.pi), 2 * np.pi * leg.turns / leg.dwell_s))
            t += leg.dwell_s
            k += 1
        p = q
    cols = list(zip(*rows, strict=True))
    return Track(np.array(cols[0]), np.array(cols[1]), np.array(cols[2]), np.array(cols[3]),
                 np.array(cols[4], dtype=int), np.array(cols[5]), np.array(cols[6]))


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
    return fly((far[0], far[1], alt), legs, rng)


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
    return fly(start, legs, rng, speed)


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
    return fly(start, legs, rng, speed=1.0)
