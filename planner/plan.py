"""The planner's output: dwell waypoints (x, y, z, yaw) and the collision-free path to the first one.

The mission layer uploads ``path`` as waypoints without hold and ``dwell_points`` as waypoints where
the dwell controller runs; ``to_topic`` gives the ``radseek.topics.Plan`` payload.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from radseek import topics


@dataclass(frozen=True)
class DwellPlan:
    """dwell_points: (K, 4) [x, y, z, yaw] (m, rad, ENU, yaw CCW from +x); path: (M, 4) from the
    current configuration to dwell_points[0], every segment collision-free; empty if planning failed."""

    dwell_points: np.ndarray
    path: np.ndarray
    method: str
    gains: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (K,) score of each dwell point
    info: dict[str, Any] = field(default_factory=dict)  # method-specific diagnostics (times, counts)

    def __post_init__(self) -> None:
        object.__setattr__(self, "dwell_points", np.asarray(self.dwell_points, dtype=float).reshape(-1, 4))
        object.__setattr__(self, "path", np.asarray(self.path, dtype=float).reshape(-1, 4))

    @property
    def ok(self) -> bool:
        return len(self.dwell_points) > 0

    def path_length(self) -> float:
        """m, length of ``path``."""
        return float(np.linalg.norm(np.diff(self.path[:, :3], axis=0), axis=1).sum()) if len(self.path) else 0.0

    def to_topic(self, t: float) -> topics.Plan:
        return topics.Plan(
            t=float(t),
            dwell_points=[float(v) for v in self.dwell_points.ravel()],  # (x, y, z, yaw) per point, one list
            path=[float(v) for v in self.path.ravel()],
        )
