"""The geofence: an axis-aligned box in local ENU metres (from ``--bounds`` or the scene), plus the zones
a ground station uploads as the FENCE mission type (polygons and circles, inclusion or exclusion).

Default box: +-1000 m east/north of home, 0-120 m above it. PX4 ships with its fence off
(GF_MAX_HOR_DIST = 0); a box is kept so that a typo in a waypoint cannot send the vehicle kilometres
away, and it is wide enough for MAVSDK's stock examples (mission_raw.py flies 554 m north). 120 m is
the EU open-category ceiling. ``--bounds`` / ``--scene`` replace it.

Zones follow PX4's rule (Geofence::checkPolygons): a point is allowed if it is inside at least one
inclusion zone (when there is any) and outside every exclusion zone, and always inside the box. A
circle of radius 0 (MAVSDK's placeholder for "no circle") is stored but encloses nothing and does not
count as an inclusion zone.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Zone:
    """A polygon (``vertices``, ENU x-y m) or a circle (``center``, ``radius`` m)."""

    inclusion: bool
    vertices: tuple[tuple[float, float], ...] = ()
    center: tuple[float, float] = (0.0, 0.0)
    radius: float = 0.0

    @property
    def degenerate(self) -> bool:
        return not self.vertices and self.radius <= 0

    def contains(self, x: float, y: float) -> bool:
        if not self.vertices:
            return math.hypot(x - self.center[0], y - self.center[1]) <= self.radius
        inside = False  # even-odd ray casting
        v = self.vertices
        for k in range(len(v)):
            (x1, y1), (x2, y2) = v[k], v[k - 1]
            if (y1 > y) != (y2 > y) and x < (x2 - x1) * (y - y1) / (y2 - y1) + x1:
                inside = not inside
        return inside


@dataclass(frozen=True)
class Geofence:
    xmin: float = -1000.0
    ymin: float = -1000.0
    zmin: float = 0.0
    xmax: float = 1000.0
    ymax: float = 1000.0
    zmax: float = 120.0
    zones: tuple[Zone, ...] = ()

    def __post_init__(self) -> None:
        if not (self.xmin < self.xmax and self.ymin < self.ymax and self.zmin < self.zmax):
            raise ValueError(f"empty geofence {self}")

    @classmethod
    def parse(cls, text: str) -> Geofence:
        """``xmin,ymin,zmin,xmax,ymax,zmax`` in metres."""
        parts = [float(v) for v in text.split(",")]
        if len(parts) != 6:
            raise ValueError(f"bounds need 6 numbers xmin,ymin,zmin,xmax,ymax,zmax, got {text!r}")
        return cls(*parts)

    def with_zones(self, zones: tuple[Zone, ...]) -> Geofence:
        return dataclasses.replace(self, zones=tuple(zones))

    def in_box(self, p: np.ndarray, tol: float = 1e-6) -> bool:
        x, y, z = (float(v) for v in p)
        return (self.xmin - tol <= x <= self.xmax + tol and self.ymin - tol <= y <= self.ymax + tol
                and self.zmin - tol <= z <= self.zmax + tol)

    def zone_violation(self, p: np.ndarray) -> str | None:
        """Why the uploaded zones forbid ``p`` (a sentence), or None if they allow it."""
        x, y = float(p[0]), float(p[1])
        inclusions = [z for z in self.zones if z.inclusion and not z.degenerate]
        if inclusions and not any(z.contains(x, y) for z in inclusions):
            return "outside every inclusion fence"
        for k, z in enumerate(self.zones):
            if not z.inclusion and not z.degenerate and z.contains(x, y):
                return f"inside exclusion fence {k}"
        return None

    def contains(self, p: np.ndarray, tol: float = 1e-6) -> bool:
        return self.in_box(p, tol) and self.zone_violation(p) is None

    def violated_axis(self, p: np.ndarray) -> int | None:
        """0, 1 or 2 (ENU east, north, up) for the first axis outside the box, None if inside."""
        lo = (self.xmin, self.ymin, self.zmin)
        hi = (self.xmax, self.ymax, self.zmax)
        for k in range(3):
            if not lo[k] - 1e-6 <= float(p[k]) <= hi[k] + 1e-6:
                return k
        return None


def zones_from_items(items: list, to_enu) -> tuple[Zone, ...]:
    """Zones from FENCE mission items (``to_enu(lat_deg, lon_deg) -> (x, y)``). Consecutive polygon
    vertices of one kind form one polygon of ``param1`` vertices; raises ValueError (with the MAVLink
    parameter at fault) when a polygon's vertex count does not match its items."""
    from pymavlink.dialects.v20 import common as M

    poly = {M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION: True, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION: False}
    circ = {M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION: True, M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION: False}
    zones: list[Zone] = []
    k = 0
    while k < len(items):
        it = items[k]
        if it.command in poly:
            n = int(it.param1)
            group = items[k:k + n]
            if len(group) < n or any(g.command != it.command or int(g.param1) != n for g in group):
                raise ValueError(f"polygon at item {k} announces {n} vertices (param1) but has {len(group)}")
            zones.append(Zone(poly[it.command], tuple(to_enu(g.x / 1e7, g.y / 1e7) for g in group)))
            k += n
        else:
            if it.command in circ:
                zones.append(Zone(circ[it.command], center=to_enu(it.x / 1e7, it.y / 1e7), radius=float(it.param1)))
            k += 1  # a fence return point is kept in the list but is no zone
    return tuple(zones)


def wall_zones(walls, margin: float = 0.0) -> tuple[Zone, ...]:
    """Mapped walls as exclusion zones: each wall's footprint (a rectangle ``thickness`` wide about its
    start-end segment) grown by ``margin`` m on every side (the vehicle's radius). 2-D like PX4's fences:
    a wall excludes its footprint at every altitude."""
    zones = []
    for w in walls:
        (ax, ay), (bx, by) = (float(v) for v in w.start), (float(v) for v in w.end)
        length = math.hypot(bx - ax, by - ay)
        if length <= 0:
            continue
        ux, uy = (bx - ax) / length, (by - ay) / length  # along the wall
        nx, ny = -uy, ux  # across it
        h = float(w.thickness) / 2 + margin
        a = (ax - ux * margin, ay - uy * margin)
        b = (bx + ux * margin, by + uy * margin)
        zones.append(Zone(False, ((a[0] + nx * h, a[1] + ny * h), (b[0] + nx * h, b[1] + ny * h),
                                  (b[0] - nx * h, b[1] - ny * h), (a[0] - nx * h, a[1] - ny * h))))
    return tuple(zones)
