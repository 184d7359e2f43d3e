"""Per-frame residual features (pure functions of frames, scenario and a source estimate).

The features are the quantities a physicist plots residuals against to see which physics is missing:
count rate (dead time), distance to the source (air attenuation, inverse-square shape), bearing of the
source in the detector frame (angular response), path length through each mapped wall (shielding),
time (drifts) and position (a residual map: unmodelled sources, background gradients).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radseek.dataset import Frames, Scenario
from radseek.geometry import path_lengths_per_wall


@dataclass(frozen=True)
class Features:
    """One value per frame for each feature; ``walls`` is (N, W)."""

    rate_cps: np.ndarray  # expected total count rate of the fitted model
    distance_m: np.ndarray  # 3-D distance to the (primary) fitted source
    bearing_deg: np.ndarray  # azimuth of the source relative to the detector axis, (-180, 180]; +-180 = behind
    back_angle_deg: np.ndarray  # 3-D angle between the detector's back direction (-axis) and the source
    walls_m: np.ndarray  # (N, W) path length through each mapped wall
    time_s: np.ndarray
    x: np.ndarray
    y: np.ndarray

    def scalar_features(self) -> dict[str, np.ndarray]:
        """Name -> (N,) values for the 1-D residual trends (walls one by one)."""
        out = {
            "count rate": self.rate_cps,
            "distance": self.distance_m,
            "bearing": self.bearing_deg,
            "time": self.time_s,
            "x": self.x,
            "y": self.y,
        }
        for w in range(self.walls_m.shape[1]):
            out[f"wall {w} path"] = self.walls_m[:, w]
        return out


UNITS = {"count rate": "cps", "distance": "m", "bearing": "deg", "time": "s", "x": "m", "y": "m"}


def unit_of(name: str) -> str:
    return "m" if name.startswith("wall") else UNITS.get(name, "")


def compute_features(frames: Frames, scenario: Scenario, source_xyz: np.ndarray, expected_counts: np.ndarray
                     ) -> Features:
    """Features of every frame for a source at ``source_xyz`` (3,) and the model's expected counts (N,)."""
    pos = frames.positions
    src = np.asarray(source_xyz, dtype=float).reshape(3)
    d = src[None, :] - pos
    dist = np.linalg.norm(d, axis=1)
    azimuth = np.arctan2(d[:, 1], d[:, 0])
    bearing = np.degrees(np.angle(np.exp(1j * (azimuth - frames.yaw))))
    back = -np.column_stack([np.cos(frames.yaw), np.sin(frames.yaw), np.zeros_like(frames.yaw)])
    cosang = np.einsum("ij,ij->i", back, d) / np.maximum(dist, 1e-9)
    back_angle = np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0)))
    if scenario.walls:
        walls = path_lengths_per_wall(pos, src[None, :], scenario.walls)
    else:
        walls = np.zeros((len(frames), 0))
    rate = np.asarray(expected_counts, dtype=float) / frames.duration
    return Features(rate, dist, bearing, back_angle, walls, frames.t.copy(), frames.x.copy(), frames.y.copy())
