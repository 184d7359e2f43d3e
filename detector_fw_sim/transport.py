"""Per-source geometric and attenuation factors (pure, vectorised over frames).

For a detector at p (N, 3) with axis heading yaw (N,) and a point source at s:

- inverse square (paper 003 eq. 1): 1 / |p - s|^2 in 3-D;
- Beer-Lambert through walls (paper 004 eq. 5.10): exp(-sum_w mu_w L_w), L_w the 3-D length of the
  segment p-s inside wall slab w (``radseek.geometry``);
- air: exp(-mu_air |p - s|);
- anisotropy (paper 003 Fig. 2, the ~50 % cone behind the detector): the source term is reduced by
  fraction * (1 - tanh((theta - half_angle) / edge)) / 2, theta the angle between the detector's
  back direction (-axis, horizontal) and the 3-D direction to the source.
"""

from __future__ import annotations

import numpy as np

from radseek.geometry import path_lengths_per_wall

MIN_DISTANCE_M = 0.05  # the crystal is 1 cm; closer than this the point-source law means nothing


def distances(p: np.ndarray, s: np.ndarray) -> np.ndarray:
    d = np.linalg.norm(np.asarray(p, dtype=float) - np.asarray(s, dtype=float), axis=-1)
    return np.maximum(d, MIN_DISTANCE_M)


def inverse_square(p: np.ndarray, s: np.ndarray) -> np.ndarray:
    return 1.0 / distances(p, s) ** 2


def wall_transmission(p: np.ndarray, s: np.ndarray, walls: np.ndarray, mu_per_m: np.ndarray) -> np.ndarray:
    """exp(-sum_w mu_w L_w); walls (W, 6) from ``radseek.geometry.wall_arrays``, mu_per_m (W,) or (W, K).

    Returns (N,) for mu (W,), (N, K) for per-line mu (W, K).
    """
    p = np.asarray(p, dtype=float)
    mu = np.asarray(mu_per_m, dtype=float)
    if len(walls) == 0:
        return np.ones(p.shape[:-1] + mu.shape[1:])
    lengths = path_lengths_per_wall(p, np.broadcast_to(s, p.shape), walls)  # (N, W)
    return np.exp(-np.tensordot(lengths, mu, axes=([-1], [0])))


def air_transmission(p: np.ndarray, s: np.ndarray, mu_per_m: np.ndarray | float) -> np.ndarray:
    """exp(-mu d): (N,) for scalar mu, (N, K) for per-line mu (K,)."""
    d = distances(p, s)
    mu = np.asarray(mu_per_m, dtype=float)
    return np.exp(-d[..., None] * mu) if mu.ndim else np.exp(-d * float(mu))


def back_angle(p: np.ndarray, yaw: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Angle (rad) between the detector's back direction (-axis, horizontal) and the direction to s."""
    p = np.asarray(p, dtype=float)
    to_src = np.asarray(s, dtype=float) - p
    norm = np.maximum(np.linalg.norm(to_src, axis=-1), 1e-12)
    back = np.stack([-np.cos(yaw), -np.sin(yaw), np.zeros_like(np.asarray(yaw, dtype=float))], axis=-1)
    cos = np.clip((to_src * back).sum(-1) / norm, -1.0, 1.0)
    return np.arccos(cos)


def anisotropy_factor(p: np.ndarray, yaw: np.ndarray, s: np.ndarray, fraction: float, half_angle_deg: float,
                      edge_deg: float) -> np.ndarray:
    """1 - fraction * (1 - tanh((theta - half_angle) / edge)) / 2."""
    theta = back_angle(p, yaw, s)
    edge = np.radians(max(edge_deg, 1e-6))
    reduction = fraction * (1 - np.tanh((theta - np.radians(half_angle_deg)) / edge)) / 2
    return 1.0 - reduction


def dead_time(n_true: np.ndarray, tau_s: float) -> np.ndarray:
    """Paralyzable dead time (paper 000 eq. 10): recorded/true = exp(-n tau), n the total true rate."""
    return np.exp(-np.asarray(n_true, dtype=float) * tau_s)
