"""True coincidence summing of a gamma cascade in one crystal (Knoll 4th ed. sec. 12.VI; Debertin & Helmer,
*Gamma- and X-ray spectrometry with semiconductor detectors*, ch. 5).

Two photons emitted together by one decay reach the crystal independently; each deposits with its total
efficiency eps_t = g T (g the solid-angle fraction, T the intrinsic interaction probability) and fully with its
photopeak efficiency eps_p. The crystal records one pulse of the summed deposit, so per decay emitting both:

    peak 1: eps_p1 (1 - eps_t2),  peak 2: eps_p2 (1 - eps_t1),  sum peak (E1 + E2): eps_p1 eps_p2

(isotropic emission; the angular correlation, 1.0-1.17 for Co-60, is left out).

Which lines come together is not typed here: pydecay's ICRP-107 tables hold yields, not level schemes. Two lines
whose yields per decay add to more than 1 must be emitted together in at least y1 + y2 - 1 of the decays
(Bonferroni), which is Co-60's 1173/1332 keV cascade (0.9983 of the decays). Cascades of weaker lines (Eu-152,
Ba-133) need coincidence intensities (paceENSDF), not installed here: for them nothing is summed.
"""

from __future__ import annotations

import math

#: a pair is summed when its yields force at least this share of the decays to emit both
MIN_FORCED = 0.5


def solid_angle_fraction(distance_mm: float, radius_mm: float) -> float:
    """Omega / 4 pi of a disc of ``radius_mm`` seen on its axis from a point ``distance_mm`` away."""
    if distance_mm < 0 or radius_mm <= 0:
        raise ValueError(f"distance {distance_mm} mm and radius {radius_mm} mm: need distance >= 0, radius > 0")
    return 0.5 * (1.0 - distance_mm / math.hypot(distance_mm, radius_mm))


def forced_pairs(yields: list[float]) -> list[tuple[int, int, float]]:
    """(i, j, c) for the lines that must be emitted together: c = y_i + y_j - 1 >= ``MIN_FORCED`` decays."""
    out = []
    for i in range(len(yields)):
        for j in range(i + 1, len(yields)):
            c = yields[i] + yields[j] - 1.0
            if c >= MIN_FORCED:
                out.append((i, j, c))
    return out


def two_photon_summing(eps_p1: float, eps_t1: float, eps_p2: float, eps_t2: float) -> tuple[float, float, float]:
    """Per decay emitting both photons: recorded (peak 1, peak 2, sum peak) counts."""
    for name, v in (("eps_p1", eps_p1), ("eps_t1", eps_t1), ("eps_p2", eps_p2), ("eps_t2", eps_t2)):
        if not 0.0 <= v <= 1.0:
            raise ValueError(f"{name} = {v}: an efficiency lies in [0, 1]")
    if eps_p1 > eps_t1 or eps_p2 > eps_t2:
        raise ValueError("a photopeak efficiency cannot exceed the total efficiency")
    return eps_p1 * (1.0 - eps_t2), eps_p2 * (1.0 - eps_t1), eps_p1 * eps_p2
