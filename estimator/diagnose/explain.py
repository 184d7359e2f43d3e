"""One sentence of physics per effect, and the residual feature each effect should remove."""

from __future__ import annotations

#: effect -> (physics a user learns from, residual feature it explains (a ``Features`` name prefix))
PHYSICS: dict[str, tuple[str, str]] = {
    "dead_time": (
        "After each pulse the electronics are blind for a few microseconds, so at high rates pulses pile up "
        "unseen and the recorded rate m = n exp(-n tau) falls below the true rate n: the detector under-counts "
        "most exactly where the source is strongest.",
        "count rate",
    ),
    "wall_attenuation": (
        "Gamma rays crossing a wall are absorbed or scattered out of the beam with probability 1 - exp(-mu L) "
        "(concrete ~0.18 /cm at 662 keV), so dwell points whose line of sight to the source crosses a wall "
        "see fewer counts than the inverse-square law predicts.",
        "wall",
    ),
    "unmapped_wall": (
        "Something the map does not show (a wall, a shelf, a vehicle, the operator's body) stands between the "
        "source and part of the flight: lines of sight through it lose a fraction 1 - exp(-mu L) of the source's "
        "photons, so a sector of directions from the source sees fewer counts than 1/d^2 predicts. The shadow "
        "fixes the sector the obstacle blocks and its mu x thickness; add it to scenario.json's walls.",
        "x",
    ),
    "anisotropy": (
        "The detector is not equally sensitive in all directions: electronics and mounting behind the crystal "
        "shield it, so a source in a cone behind the detector axis is seen with reduced efficiency and the "
        "count rate depends on the heading, not only on the distance.",
        "bearing",
    ),
    "air_attenuation": (
        "Air itself attenuates 662 keV photons (mu ~ 0.0093 /m), which is negligible at 2 m but removes ~10 % "
        "of the flux over 10 m, so far dwell points see fewer counts than 1/d^2 predicts.",
        "distance",
    ),
    "second_source": (
        "A second radioactive source adds its own inverse-square hill to the count-rate map, so counts are in "
        "excess near a place the one-source model does not explain.",
        "x",
    ),
    "background_gradient": (
        "Natural background (soil potassium, uranium, thorium, building materials) is not uniform: it changes "
        "across the site, so the far-from-source rate depends on where the drone is.",
        "x",
    ),
    "gain_drift": (
        "The scintillator light yield and SiPM gain change with temperature, so the pulse height of a given "
        "energy drifts with time and spectral features (the 662 keV photopeak) slide across the fixed "
        "comparator edges while the total count rate barely changes.",
        "spectral channel over time",
    ),
    "pose_drift": (
        "Odometry drifts: the recorded position wanders away from the true one at a roughly constant velocity, "
        "so late in the flight the count rate matches a source displaced along the drift and residuals grow "
        "with time. A source that itself moves at -v leaves the same counts (only the relative position "
        "matters): from counts alone the two cannot be told apart.",
        "time",
    ),
    "over_dispersion": (
        "Real detectors count with more than Poisson scatter: electronic noise bursts, a vibrating mount or an "
        "unsteady bias voltage make each frame's rate fluctuate on its own, so consecutive frames differ more "
        "than counting statistics allow (negative binomial counts, Var = mu + r^2 mu^2); it is not a missing "
        "source or wall, and the evidence for those is discounted by it.",
        "frame-to-frame scatter",
    ),
}

#: a second unmapped wall is the same physics
PHYSICS["unmapped_wall_2"] = PHYSICS["unmapped_wall"]


def physics(effect: str) -> str:
    return PHYSICS.get(effect, (f"{effect}: an effect this version of diagnose has no explanation for.", ""))[0]


def feature_of(effect: str) -> str:
    return PHYSICS.get(effect, ("", ""))[1]
