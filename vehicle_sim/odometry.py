"""Pure GPS-denied pose estimate (paper 003: visual-inertial odometry): the estimate drifts from the
truth as a random walk whose variance grows linearly with the distance flown, and the variance is
reported alongside it. No drift accrues while hovering still.

Drift state ``d = estimate - truth`` over (x, y, z, yaw); ``var`` its per-axis variance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class OdometryParams:
    """Random-walk densities: the drift's standard deviation after flying 1 m."""

    sigma_xy: float = 0.03  # m / sqrt(m), [0, 1]
    sigma_z: float = 0.01  # m / sqrt(m), [0, 1]
    sigma_yaw: float = math.radians(0.2)  # rad / sqrt(m), [0, 0.1]
    initial_var: float = 1e-4  # m^2 (and rad^2), variance at start

    def __post_init__(self) -> None:
        for name, hi in (("sigma_xy", 1), ("sigma_z", 1), ("sigma_yaw", 0.1), ("initial_var", 1)):
            v = getattr(self, name)
            if not (0 <= v <= hi):
                raise ValueError(f"{name}={v} must be in [0, {hi}]")

    @property
    def density(self) -> np.ndarray:
        """Variance added per metre flown, per axis (x, y, z, yaw)."""
        return np.array([self.sigma_xy, self.sigma_xy, self.sigma_z, self.sigma_yaw]) ** 2


def propagate(
    drift: np.ndarray, var: np.ndarray, distance: float, normals: np.ndarray, params: OdometryParams
) -> tuple[np.ndarray, np.ndarray]:
    """Advance the drift by ``distance`` m flown, with standard normal draws ``normals`` (shape (4,))."""
    distance = max(float(distance), 0.0)
    dens = params.density
    return drift + np.sqrt(dens * distance) * normals, var + dens * distance


class Odometry:
    """The vehicle's estimator: seeded random walk on top of the true motion."""

    def __init__(self, params: OdometryParams | None = None, seed: int = 0):
        self.params = params or OdometryParams()
        self._rng = np.random.default_rng(seed)
        self.drift = np.zeros(4)
        self.var = np.full(4, self.params.initial_var)
        self.distance = 0.0

    def advance(self, distance: float) -> None:
        if distance <= 0:
            return
        self.distance += distance
        self.drift, self.var = propagate(self.drift, self.var, distance, self._rng.standard_normal(4), self.params)

    def truth_from_estimate(self, est_pos: np.ndarray, est_yaw: float) -> tuple[np.ndarray, float]:
        """The controller flies on the estimate, so the truth is the estimate minus the drift."""
        return np.asarray(est_pos, dtype=float) - self.drift[:3], est_yaw - float(self.drift[3])
