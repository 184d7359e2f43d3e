"""Frame conversions at the MAVLink edge: local ENU (the stack's frame) <-> NED <-> lat/lon/alt.

Inside radseek everything is local ENU metres about the home point, yaw CCW from +x (east).
MAVLink speaks NED (yaw CW from north) and WGS-84 degrees; these functions are the only place
that converts. A flat-earth (local tangent plane) approximation is used: exact to millimetres over
the few hundred metres a dwell-point search covers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

EARTH_RADIUS_M = 6378137.0  # WGS-84 equatorial radius


@dataclass(frozen=True)
class Home:
    """The home point: origin of the local ENU frame (PX4 SITL's default location)."""

    lat_deg: float = 47.397742
    lon_deg: float = 8.545594
    alt_m: float = 488.0  # AMSL

    def __post_init__(self) -> None:
        if not (-89.0 <= self.lat_deg <= 89.0 and -180.0 <= self.lon_deg <= 180.0):
            raise ValueError(f"home {self.lat_deg}, {self.lon_deg} is not a valid position")


def wrap_pi(a: float) -> float:
    """Angle wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def enu_to_ned(v: np.ndarray) -> np.ndarray:
    """(e, n, u) -> (n, e, d); works for positions and velocities, shape (..., 3)."""
    v = np.asarray(v, dtype=float)
    return np.stack([v[..., 1], v[..., 0], -v[..., 2]], axis=-1)


def yaw_enu_to_ned(yaw_enu: float) -> float:
    """ENU yaw (CCW from east) -> NED yaw (CW from north), both rad, wrapped."""
    return wrap_pi(math.pi / 2.0 - yaw_enu)


def yaw_ned_to_enu(yaw_ned: float) -> float:
    return wrap_pi(math.pi / 2.0 - yaw_ned)


def enu_to_geodetic(home: Home, p_enu: np.ndarray) -> tuple[float, float, float]:
    """Local ENU metres -> (lat deg, lon deg, alt m AMSL)."""
    e, n, u = (float(c) for c in p_enu)
    lat = home.lat_deg + math.degrees(n / EARTH_RADIUS_M)
    lon = home.lon_deg + math.degrees(e / (EARTH_RADIUS_M * math.cos(math.radians(home.lat_deg))))
    return lat, lon, home.alt_m + u


def geodetic_to_enu(home: Home, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> np.ndarray:
    """(lat deg, lon deg, alt m AMSL) -> local ENU metres."""
    n = math.radians(lat_deg - home.lat_deg) * EARTH_RADIUS_M
    e = math.radians(lon_deg - home.lon_deg) * EARTH_RADIUS_M * math.cos(math.radians(home.lat_deg))
    return np.array([e, n, alt_amsl_m - home.alt_m])
