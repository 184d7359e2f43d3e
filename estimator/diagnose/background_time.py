"""Did the background change in time? The verdict's check of a model that needed count effects to fit.

A background that varies during the flight (radon washed out by rain, a truck with a load passing by, a drifting
electronic baseline) is off the dataset spec's list. Its counts can be fitted within their noise by a named effect
standing in for it: a second source where the flight happened to be when the background rose, a background gradient
along a lawnmower's sweep. When a count effect was named, the start model (no named effects) plus
``background_drift`` (``estimator.model.BackgroundDrift``: B (1 + a sin(2 pi t / P + phase) + r t)) is fitted with
the period P free, from starts spread over the frequencies a flight of span T can tell apart (spacing 1 / T, from
1 / (2 T) to 1 / :data:`MIN_PERIOD_S`). If its AIC is lower than the named model's by :data:`STRONG_AIC` plus the
look-elsewhere allowance 2 ln(number of frequency starts), the named effects are not the physics: a background
changing in time explains the counts better, and the verdict says so.

The same comparison as the moved-source check (``estimator.diagnose.motion``): a non-nested AIC (Burnham and
Anderson), one alternative family, its looks paid for.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimator.diagnose.verdict import aic_gap, off_list_threshold
from estimator.mle import fit
from estimator.model import MeasurementModel
from radseek.dataset import Frames

#: the shortest period looked at (s): faster changes show frame to frame, as overdispersion
#: (``estimator.diagnose.dispersion``), not as a trend
MIN_PERIOD_S = 15.0
#: the relative amplitude each start begins at (its sign and the start phases cover the circle)
START_AMPLITUDE = 0.1
NAME = "background_drift"
FREE = (f"{NAME}.amplitude", f"{NAME}.phase", f"{NAME}.period_s", f"{NAME}.percent_per_min")


@dataclass(frozen=True)
class BackgroundTimeCheck:
    """The best fit of a background changing in time: its period, amplitude and ramp (with 1-sigma errors), and the
    AIC of the named model minus this one's (positive: the changing background is better)."""

    period_s: float
    amplitude: float
    amplitude_err: float
    percent_per_min: float
    background_cps: float
    aic_gap: float
    threshold: float
    looks: int

    @property
    def significant(self) -> bool:
        return self.aic_gap >= self.threshold

    def text(self) -> str:
        return (f"a background of {self.background_cps:.1f} cps changing in time (by {100 * abs(self.amplitude):.0f} % "
                f"with a period of {self.period_s:.0f} s, and {self.percent_per_min:+.1f} %/min) fits the counts "
                f"better than the named effects (AIC lower by {self.aic_gap:.0f}, needed {self.threshold:.0f}): the "
                "background varied during the flight")

    def to_json(self) -> dict[str, Any]:
        return {"period_s": round(self.period_s, 2), "amplitude": round(self.amplitude, 4),
                "amplitude_err": round(self.amplitude_err, 4) if math.isfinite(self.amplitude_err) else None,
                "percent_per_min": round(self.percent_per_min, 3), "background_cps": round(self.background_cps, 3),
                "aic_gap": round(self.aic_gap, 2), "threshold": round(self.threshold, 2), "looks": self.looks,
                "significant": self.significant}


def period_starts(frames: Frames, min_period_s: float = MIN_PERIOD_S) -> np.ndarray:
    """Starting periods (s): frequencies 1 / T apart from 1 / (2 T) up to 1 / ``min_period_s``, T the flight's span
    (at least one)."""
    span = max(float(frames.t[-1] - frames.t[0]), 2 * min_period_s)
    f = np.arange(0.5 / span, 1.0 / min_period_s + 1e-12, 1.0 / span)
    return 1.0 / f


def background_time_check(start: MeasurementModel, frames: Frames, named: Any, seed: int = 0
                          ) -> BackgroundTimeCheck:
    """The start model ``start`` (the effects the user gave) with its background changing in time, against the
    ``named`` FitResult (the start model with the named effects) on the same ``frames``."""
    periods = period_starts(frames)
    threshold = off_list_threshold(len(periods))
    span = float(frames.t[-1] - frames.t[0])
    m = MeasurementModel(start.scenario, (*start.effects, NAME), start.channels)
    m = m.with_params(**{f"{NAME}.period_s": {"value": float(periods[0]), "fixed": False,
                                              "lower": MIN_PERIOD_S * 0.8, "upper": 4 * max(span, MIN_PERIOD_S)},
                         f"{NAME}.phase": {"value": 0.0, "fixed": False}})
    base = {k: v for k, v in named.values.items() if k in m.param_names}
    inits = [{**base, f"{NAME}.period_s": float(p), f"{NAME}.phase": ph, f"{NAME}.amplitude": START_AMPLITUDE}
             for p in periods for ph in (0.0, math.pi / 2)]
    res = fit(m, frames, n_starts=len(inits), seed=seed, init=inits[0], more_inits=inits[1:], hover=True)
    gap = aic_gap(named, res)
    v, e = res.values, res.errors
    return BackgroundTimeCheck(float(v[f"{NAME}.period_s"]), float(v[f"{NAME}.amplitude"]),
                               float(e.get(f"{NAME}.amplitude", math.nan)), float(v[f"{NAME}.percent_per_min"]),
                               float(v.get("background_cps", math.nan)), float(gap), threshold, len(periods))
