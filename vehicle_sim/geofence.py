"""The geofence: an axis-aligned box in local ENU metres (from ``--bounds`` or the scene)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Geofence:
    xmin: float = -500.0
    ymin: float = -500.0
    zmin: float = 0.0
    xmax: float = 500.0
    ymax: float = 500.0
    zmax: float = 120.0

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

    def contains(self, p: np.ndarray, tol: float = 1e-6) -> bool:
        x, y, z = (float(v) for v in p)
        return (self.xmin - tol <= x <= self.xmax + tol and self.ymin - tol <= y <= self.ymax + tol
                and self.zmin - tol <= z <= self.zmax + tol)

    def violated_axis(self, p: np.ndarray) -> int | None:
        """0, 1 or 2 for the first axis outside the box, None if inside."""
        lo = (self.xmin, self.ymin, self.zmin)
        hi = (self.xmax, self.ymax, self.zmax)
        for k in range(3):
            if not lo[k] - 1e-6 <= float(p[k]) <= hi[k] + 1e-6:
                return k
        return None
