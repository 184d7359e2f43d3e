"""The expected count rate of a point source: the physics every localizer and the planner share.

Paper 003 eq. 1-4 (dataset-format.md's baseline model): a point source of strength S (``cps_at_1m``,
paper 003's A e v_s / 4 pi) at squared distance d^2 from the detector, seen through a transmission
factor a (walls: exp(-mu L), paper 004 eq. 5.19; air, anisotropy: ``estimator.model``'s effects), over a
background B, gives the true rate

    n = S a / max(d^2, d_min^2) + B

and a paralyzable counter of dead time tau records (paper 000 eq. 10)

    m = n exp(-n tau).

It lives in the contracts package because both the estimator and the planner need it and neither may
import the other (tests/test_architecture.py); the simulated world keeps its own physics (the truth the
model is tested against).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["MIN_DISTANCE_M", "dead_time", "expected_rate"]

#: closer than this the point-source law means nothing (the crystal is 1 cm): distances are clamped here
MIN_DISTANCE_M = 0.05


def dead_time(n: Any, tau_s: Any) -> Any:
    """Recorded rate of a paralyzable counter at true total rate ``n`` (paper 000 eq. 10): n exp(-n tau)."""
    return n * np.exp(-n * tau_s)


def expected_rate(d2: Any, cps_at_1m: Any, background_cps: Any = 0.0, tau_s: Any = 0.0,
                  attenuation: Any = None) -> Any:
    """Recorded count rate (cps) of one point source at squared distance ``d2`` (m^2) from the detector.

    n = cps_at_1m * attenuation / max(d2, MIN_DISTANCE_M^2) + background_cps (paper 003 eq. 1-4), then
    dead time m = n exp(-n tau_s) (paper 000 eq. 10). Pure and vectorised: all arguments broadcast
    (particles x frames, grid cells x frames ...). With ``cps_at_1m=1`` and no background it is the
    geometric gain of a unit source; for several sources sum their net rates, add the background and apply
    :func:`dead_time` to the total.
    """
    n = np.divide(cps_at_1m, np.maximum(d2, MIN_DISTANCE_M**2))
    if attenuation is not None:
        n = n * attenuation
    n = n + background_cps
    return dead_time(n, tau_s) if np.any(tau_s) else n
