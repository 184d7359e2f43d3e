"""Occupancy and validity from the mapped walls, inflated by the vehicle's radius.

Paper 003 sec. IV-B-1 keeps a voxel occupancy map M; here the map is the scene's walls (vertical slabs,
``radseek.dataset.Wall``) inside an axis-aligned flight volume. A configuration is valid when the
vehicle's centre is inside the volume shrunk by its radius and outside every wall grown by the radius
(sideways, along the wall and on top). A straight motion is valid when its whole segment misses every
grown wall: this is an exact, continuous test (slab intersection, ``radseek.geometry.path_lengths``),
so it cannot cut corners at any resolution, unlike sampling the segment. A slab grown by r on every
face contains every point within r of the wall, so a valid segment keeps the vehicle's sphere clear.

``OccupancyMap.grid`` rasterises the same test for plots and frontier exploration.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from radseek.dataset import Scenario, Wall
from radseek.geometry import segment_hits_walls, wall_arrays


def inflate_walls(walls: Sequence[Wall] | np.ndarray, radius: float) -> np.ndarray:
    """(W, 6) wall array grown by ``radius`` along the wall, across it and on top (not below z = 0)."""
    w = (walls if isinstance(walls, np.ndarray) else wall_arrays(walls)).astype(float).copy()
    if len(w) == 0 or radius == 0:
        return w
    s0, s1 = w[:, 0:2].copy(), w[:, 2:4].copy()
    length = np.linalg.norm(s1 - s0, axis=1, keepdims=True)
    u = np.where(length > 0, (s1 - s0) / np.where(length > 0, length, 1.0), np.array([[1.0, 0.0]]))
    w[:, 0:2] = s0 - radius * u
    w[:, 2:4] = s1 + radius * u
    w[:, 4] += 2 * radius
    w[:, 5] += radius
    return w


@dataclass(frozen=True)
class OccupancyMap:
    """Flight volume [bounds_min, bounds_max] (m) and walls grown by the vehicle ``radius`` (m, >= 0)."""

    bounds_min: np.ndarray
    bounds_max: np.ndarray
    walls: tuple[Wall, ...] = ()
    radius: float = 0.3
    grown: np.ndarray = field(init=False, repr=False)
    _frames: tuple = field(init=False, repr=False)
    _box: tuple = field(init=False, repr=False)

    def __post_init__(self) -> None:
        lo = np.asarray(self.bounds_min, dtype=float).reshape(3)
        hi = np.asarray(self.bounds_max, dtype=float).reshape(3)
        if self.radius < 0:
            raise ValueError("radius must be >= 0")
        if np.any(hi - lo < 0):
            raise ValueError("bounds_max must be >= bounds_min")
        object.__setattr__(self, "bounds_min", lo)
        object.__setattr__(self, "bounds_max", hi)
        object.__setattr__(self, "walls", tuple(self.walls))
        grown = inflate_walls(self.walls, self.radius)
        object.__setattr__(self, "grown", grown)
        # per grown wall: origin, unit direction, length, half thickness, height (for the scalar test)
        frames = []
        for x0, y0, x1, y1, th, h in grown:
            length = math.hypot(x1 - x0, y1 - y0)
            ux, uy = ((x1 - x0) / length, (y1 - y0) / length) if length > 0 else (1.0, 0.0)
            frames.append((x0, y0, ux, uy, length, th / 2, h))
        object.__setattr__(self, "_frames", tuple(frames))
        lo_f, hi_f = self.free_min, self.free_max
        object.__setattr__(self, "_box", (*map(float, lo_f), *map(float, hi_f)))

    @classmethod
    def from_scenario(cls, scenario: Scenario, radius: float = 0.3, flight_z: tuple[float, float] = (0.5, 2.5)
                      ) -> OccupancyMap:
        """The flight volume over a scenario: its x-y bounds (where the source is known to be, per
        dataset-format.md) at altitudes ``flight_z`` (m), with its walls."""
        lo = np.array([scenario.bounds_min[0], scenario.bounds_min[1], flight_z[0]])
        hi = np.array([scenario.bounds_max[0], scenario.bounds_max[1], flight_z[1]])
        return cls(lo, hi, scenario.walls, radius)

    @property
    def free_min(self) -> np.ndarray:
        """Lowest valid vehicle-centre position: bounds shrunk by the radius in x and y."""
        return self.bounds_min + np.array([self.radius, self.radius, 0.0])

    @property
    def free_max(self) -> np.ndarray:
        return self.bounds_max - np.array([self.radius, self.radius, 0.0])

    def points_valid(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) -> (...,) bool: inside the shrunk volume and outside every grown wall."""
        p = np.asarray(points, dtype=float)
        ok = np.all((p >= self.free_min - 1e-12) & (p <= self.free_max + 1e-12), axis=-1)
        if len(self.grown):
            ok &= ~segment_hits_walls(p, p, self.grown)
        return ok

    def segments_valid(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(..., 3) x (..., 3) -> (...,) bool: both ends valid and the segment misses every grown wall."""
        ok = self.points_valid(a) & self.points_valid(b)
        if len(self.grown):
            ok &= ~segment_hits_walls(a, b, self.grown)
        return ok

    def nearest_valid(self, point: Sequence[float], max_shift: float = 0.5, step: float = 0.01) -> np.ndarray | None:
        """``point`` (x, y, z) itself if valid, else the closest valid point at the same height within
        ``max_shift`` m in x-y (rings ``step`` apart, 64 bearings each), None if there is none. A vehicle that
        arrived within its acceptance radius of a point on the clearance's edge may sit just inside a grown
        wall: it plans from here."""
        p = np.asarray(point, dtype=float).reshape(3)
        if self.point_valid(*p):
            return p.copy()
        radii = np.arange(step, max_shift + step / 2, step)
        bearings = np.linspace(0.0, 2 * np.pi, 64, endpoint=False)
        r, b = np.meshgrid(radii, bearings, indexing="ij")
        cand = np.stack([p[0] + r * np.cos(b), p[1] + r * np.sin(b), np.full_like(r, p[2])], axis=-1)
        ok = self.points_valid(cand)
        if not ok.any():
            return None
        ring = int(np.argmax(ok.any(axis=1)))
        return cand[ring, int(np.argmax(ok[ring]))]

    def point_valid(self, x: float, y: float, z: float) -> bool:
        """Scalar ``points_valid`` without numpy overhead (for OMPL's per-state callback)."""
        x0_, y0_, z0_, x1_, y1_, z1_ = self._box
        if not (x0_ <= x <= x1_ and y0_ <= y <= y1_ and z0_ <= z <= z1_):
            return False
        for x0, y0, ux, uy, length, half, h in self._frames:
            rx, ry = x - x0, y - y0
            s = rx * ux + ry * uy
            if 0.0 <= s <= length and abs(ry * ux - rx * uy) <= half and 0.0 <= z <= h:
                return False
        return True

    def segment_valid(self, a: Sequence[float], b: Sequence[float]) -> bool:
        """Scalar ``segments_valid``: exact slab clipping in each grown wall's frame, pure Python.

        The volume is a box (convex), so both ends inside it puts the segment inside; the clipping over
        t in [0, 1] also catches an end inside a wall."""
        ax, ay, az = a[0], a[1], a[2]
        bx, by, bz = b[0], b[1], b[2]
        x0_, y0_, z0_, x1_, y1_, z1_ = self._box
        if not (x0_ <= ax <= x1_ and y0_ <= ay <= y1_ and z0_ <= az <= z1_
                and x0_ <= bx <= x1_ and y0_ <= by <= y1_ and z0_ <= bz <= z1_):
            return False
        dx, dy, dz = bx - ax, by - ay, bz - az
        for x0, y0, ux, uy, length, half, h in self._frames:
            rx, ry = ax - x0, ay - y0
            # local coordinates along the wall (s), across it (n) and up (z)
            p0 = (rx * ux + ry * uy, rx * uy - ry * ux, az)
            d = (dx * ux + dy * uy, dx * uy - dy * ux, dz)
            t0, t1 = 0.0, 1.0
            for k, lo, hi in ((0, 0.0, length), (1, -half, half), (2, 0.0, h)):
                p, dd = p0[k], d[k]
                if dd == 0.0:
                    if p < lo or p > hi:
                        t0 = 2.0  # parallel and outside this slab: no hit
                        break
                    continue
                ta, tb = (lo - p) / dd, (hi - p) / dd
                if ta > tb:
                    ta, tb = tb, ta
                if ta > t0:
                    t0 = ta
                if tb < t1:
                    t1 = tb
                if t0 > t1:
                    break
            if t0 <= t1:
                return False
        return True

    def grid(self, resolution: float, z: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell centres xs (nx,), ys (ny,) and a (ny, nx) bool map of *occupied* cells at altitude z."""
        lo, hi = self.bounds_min, self.bounds_max
        nx = max(1, int(math.ceil((hi[0] - lo[0]) / resolution)))
        ny = max(1, int(math.ceil((hi[1] - lo[1]) / resolution)))
        xs = lo[0] + (np.arange(nx) + 0.5) * (hi[0] - lo[0]) / nx
        ys = lo[1] + (np.arange(ny) + 0.5) * (hi[1] - lo[1]) / ny
        gx, gy = np.meshgrid(xs, ys)
        pts = np.stack([gx, gy, np.full_like(gx, z)], axis=-1)
        return xs, ys, ~self.points_valid(pts)
