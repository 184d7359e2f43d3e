"""Did the source move? The verdict's check of a model that needed several effects to fit.

A source carried off mid-flight is off the dataset spec's list, and the counts can be fitted within their noise
by several named effects standing in for it (a pose drift, a second source where it went, a background gradient,
an unmapped wall). When two or more count effects were named, the start model (no named effects) plus
``source_motion`` (``estimator.model.SourceMotion``: the source still until t0, then moving at a constant
velocity) is fitted at a few break times t0. If its AIC is lower than the named model's by
:data:`STRONG_AIC` plus the look-elsewhere allowance 2 ln(number of break times: 13, 0.05 of the flight apart),
the named effects are not the
physics: one moved source explains the counts better with fewer parameters, and the verdict says so.

Measured (docs/diagnose-evaluation.md): on flights whose source was carried off at 0.02-0.1 m/s the true model
beats the named one by an AIC of -1 to +7 in five of six (the counts cannot tell them apart; no test can) and by
141 in the sixth, which named four effects.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimator.diagnose.verdict import aic_gap, off_list_threshold
from estimator.mle import fit
from estimator.model import MeasurementModel
from radseek.dataset import Frames

#: break times, as fractions of the flight (each keeps a fifth of the flight on either side): every other one is
#: fitted, then the two beside the best; the test pays for all of them (the maximum over a subset of the looks is
#: at most the maximum over all)
BREAKS = tuple(round(0.2 + 0.05 * k, 2) for k in range(13))
#: starting speeds (m/s) of the velocity search, in eight directions each: a slow drift to a walk
START_SPEEDS = (0.05, 0.2, 0.8)
NAME = "source_motion"


@dataclass(frozen=True)
class MotionCheck:
    """The best break: its time, the fitted source and velocity (with 1-sigma errors), and the AIC of the named
    model minus the moving source's (positive: the moving source is better)."""

    t0_s: float
    velocity: tuple[float, float]
    velocity_err: tuple[float, float]
    start_xy: tuple[float, float]
    aic_gap: float
    threshold: float

    @property
    def significant(self) -> bool:
        return self.aic_gap >= self.threshold

    def text(self) -> str:
        vx, vy = self.velocity
        x, y = self.start_xy
        return (f"one source at ({x:.2f}, {y:.2f}) m, still until t = {self.t0_s:.0f} s and then moving at "
                f"({vx:+.3f}, {vy:+.3f}) m/s, fits the counts better than the named effects (AIC lower by "
                f"{self.aic_gap:.0f}, needed {self.threshold:.0f}): a source moved mid-flight, or the recorded "
                f"pose failed from then on")

    def to_json(self) -> dict[str, Any]:
        return {"from_s": round(self.t0_s, 2), "start_xy": [round(v, 3) for v in self.start_xy],
                "velocity_m_s": [round(v, 5) for v in self.velocity],
                "velocity_err_m_s": [round(v, 5) if math.isfinite(v) else None for v in self.velocity_err],
                "aic_gap": round(self.aic_gap, 2), "threshold": round(self.threshold, 2),
                "significant": self.significant}


def break_times(frames: Frames, fractions: tuple[float, ...] = BREAKS) -> np.ndarray:
    """The looks' break times (s): the given fractions of the flight's span."""
    t0, t1 = float(frames.t[0]), float(frames.t[-1])
    return t0 + np.asarray(fractions, dtype=float) * (t1 - t0)


def velocity_starts(speeds: tuple[float, ...] = START_SPEEDS, n_dir: int = 8) -> list[dict[str, float]]:
    """Starting velocities: no motion, then each speed in ``n_dir`` directions."""
    out = [{f"{NAME}.vx": 0.0, f"{NAME}.vy": 0.0}]
    for s in speeds:
        for a in np.arange(n_dir) * 2 * np.pi / n_dir:
            out.append({f"{NAME}.vx": float(s * np.cos(a)), f"{NAME}.vy": float(s * np.sin(a))})
    return out


class MotionSearch:
    """The moved-source check's looks as independent fits, so that a caller can run them side by side: every other
    break first (:meth:`first_looks`), then the best one's two neighbours (:meth:`next_looks`), then the verdict
    (:meth:`result`). Looks are named by the index of their break."""

    def __init__(self, start: MeasurementModel, frames: Frames, named: Any, seed: int = 0):
        self.start, self.frames, self.named, self.seed = start, frames, named, seed
        self.looks = break_times(frames)

    def _look(self, i: int) -> Callable[[], Any]:
        t0 = float(self.looks[i])

        def fit_look() -> Any:
            m = MeasurementModel(self.start.scenario, (*self.start.effects, NAME), self.start.channels)
            m = m.with_params(**{f"{NAME}.t0": {"value": t0, "fixed": True}})
            base = {k: v for k, v in self.named.values.items() if k in m.param_names}
            inits = [{**base, **v, f"{NAME}.t0": t0} for v in velocity_starts()]
            return fit(m, self.frames, n_starts=len(inits), seed=self.seed, init=inits[0], more_inits=inits[1:],
                       hover=True)

        return fit_look

    def first_looks(self) -> dict[str, Callable[[], Any]]:
        return {f"look {i}": self._look(i) for i in range(0, len(self.looks), 2)}

    def next_looks(self, fits: Mapping[str, Any]) -> dict[str, Callable[[], Any]]:
        gaps = {int(k.split()[1]): aic_gap(self.named, r) for k, r in fits.items()}
        top = max(gaps, key=gaps.__getitem__)
        return {f"look {i}": self._look(i) for i in (top - 1, top + 1) if 0 <= i < len(self.looks) and i not in gaps}

    def result(self, fits: Mapping[str, Any]) -> MotionCheck:
        threshold = off_list_threshold(len(self.looks))
        i, res = max(((int(k.split()[1]), r) for k, r in fits.items()), key=lambda kr: aic_gap(self.named, kr[1]))
        v, e = (tuple(float(r.get(f"{NAME}.{k}", np.nan)) for k in ("vx", "vy")) for r in (res.values, res.errors))
        return MotionCheck(float(self.looks[i]), v, e, (float(res.values["x"]), float(res.values["y"])),
                           float(aic_gap(self.named, res)), threshold)


def run_in_turn(calls: Mapping[str, Callable[[], Any]]) -> dict[str, Any]:
    """Each call's result, one after the other (the default runner of independent fits)."""
    return {k: f() for k, f in calls.items()}


def motion_check(start: MeasurementModel, frames: Frames, named: Any, seed: int = 0,
                 run: Callable[[Mapping[str, Callable[[], Any]]], dict[str, Any]] = run_in_turn) -> MotionCheck:
    """The start model ``start`` (the effects the user gave) with a source moving from each break on, against the
    ``named`` FitResult (the start model with the named effects) on the same ``frames``; ``run`` runs a batch of
    independent looks (in parallel processes in ``radseek diagnose``)."""
    search = MotionSearch(start, frames, named, seed)
    fits = run(search.first_looks())
    fits.update(run(search.next_looks(fits)))
    return search.result(fits)
