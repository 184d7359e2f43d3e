"""The in-flight estimate: the one policy the mission flies with and ``radseek replay`` reproduces.

After each dwell the mission hands :class:`InflightEstimator` every frame recorded so far; it answers with
an estimate record (a JSON-able dict, see :meth:`InflightEstimator.update`) and keeps the history it
warm-starts from. The policy, in order:

1. fewer than ``MIN_FRAMES`` frames: no estimate;
2. pool each dwell's frames ``POOL_FRAMES`` at a time (``estimator.mle.pooled``, transit frames stay single):
   in-flight models depend on the pose only, so 1 s chunks of a dwell lose nothing but jitter;
3. fit the localizer (``mle`` with few starts and no CRLB, so the vehicle does not hover idle),
   warm-started from the previous estimate;
4. wall shadow test: if the scenario maps walls (and the settings do not choose the effects), a wall matters
   only where a recorded line of sight to the source crosses it; then refit with ``wall_attenuation``
   (warm-started from the last walled estimate) and keep the wall-free fit if that refit fails;
5. repair the position covariance (non-finite -> 0, symmetrise, clip negative eigenvalues);
6. :func:`sigma_m`: the one definition of the estimate's 1-sigma.

``mission.search.SearchBrain`` calls it and only decides; ``estimator.replay_cli`` calls it dwell by dwell
on a recorded flight and so reproduces the flown estimates.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from estimator.localizers.base import Localizer, make_localizer
from estimator.mle import pooled
from radseek.dataset import Frames, Scenario
from radseek.geometry import path_lengths, semi_major_axis

__all__ = ["DEFAULT_LOCALIZER", "DEFAULT_SETTINGS", "MIN_SIGMA_M", "InflightEstimator", "repair_covariance",
           "sigma_m"]

DEFAULT_LOCALIZER = "mle"
#: in flight the estimate is refitted after every dwell: warm-started from the previous one (when the
#: localizer takes ``init``), with few extra starts and no CRLB, so the vehicle does not hover idle
DEFAULT_SETTINGS: Mapping[str, Any] = {"n_starts": 3, "compute_crlb": False}
MIN_FRAMES = 10  # frames recorded before the first fit is tried
POOL_FRAMES = 10  # frames pooled per chunk of a dwell (1 s at 10 Hz)
#: m: a smaller 1-sigma is a numerical artefact, not certainty (per-dwell pose offsets are centimetres)
MIN_SIGMA_M = 5e-3
_INIT_KEYS = ("x", "y", "cps_at_1m", "background_cps")
_FIT_ERRORS = (ValueError, np.linalg.LinAlgError, RuntimeError)


def sigma_m(covariance: Any, converged: bool = True) -> float:
    """The estimate's 1-sigma (m): the semi-major axis of the x-y position ellipse of ``covariance``
    (any square matrix over (x, y, ...), e.g. the 4 x 4 over (x, y, z, cps_at_1m) of an ``estimate``),
    if the estimate is trustworthy, else inf. Not trustworthy: a fit that did not converge, a non-finite
    covariance, or one collapsed below ``MIN_SIGMA_M`` (parameters pinned at a bound) proves nothing."""
    cov = np.asarray(covariance, dtype=float)
    if not converged or cov.ndim != 2 or min(cov.shape) < 2 or not np.isfinite(cov[:2, :2]).all():
        return math.inf
    sigma = semi_major_axis(cov[:2, :2])
    return sigma if math.isfinite(sigma) and sigma > MIN_SIGMA_M else math.inf


def repair_covariance(covariance: Any) -> np.ndarray:
    """The (3, 3) position block of a fit's covariance made a covariance: non-finite entries 0,
    symmetric, negative eigenvalues (round-off of a nearly singular Fisher inverse) clipped to 0."""
    cov = np.asarray(covariance, dtype=float)[:3, :3]
    cov = np.where(np.isfinite(cov), cov, 0.0)
    cov = 0.5 * (cov + cov.T)
    w, v = np.linalg.eigh(cov)
    return (v * np.clip(w, 0, None)) @ v.T


class InflightEstimator:
    """Feed it the frames recorded so far after each dwell; it returns the estimate record (or None).

    ``estimates`` is its history, one record per successful fit; ``localizer`` the last fitted localizer
    (for publishing the full ``estimate`` message). A record has ``dwell`` (the caller's dwell count),
    ``x``, ``y``, ``z`` (m), ``cps_at_1m``, ``background_cps`` (cps), ``covariance`` ((3, 3) position
    covariance in m^2, repaired, as nested lists), ``sigma_m`` (:func:`sigma_m`), ``effects`` (the fitted
    model's) and ``converged``.
    """

    def __init__(self, scenario: Scenario, localizer: str = DEFAULT_LOCALIZER,
                 settings: Mapping[str, Any] | None = None):
        self.scenario = scenario
        self.method = localizer
        self.settings = dict(DEFAULT_SETTINGS if settings is None else settings)
        self.estimates: list[dict[str, Any]] = []
        self.localizer: Localizer | None = None

    @property
    def estimate(self) -> dict[str, Any] | None:
        return self.estimates[-1] if self.estimates else None

    def update(self, frames: Frames, dwell: int) -> dict[str, Any] | None:
        """Estimate from every frame recorded so far, after ``dwell`` dwell points; None if too few
        frames or the fit failed (the history is then unchanged)."""
        if len(frames) < MIN_FRAMES:
            return None
        frames = pooled(frames, POOL_FRAMES, dwells_only=True)
        settings = dict(self.settings)
        if self.estimates:
            settings["init"] = {k: self.estimates[-1][k] for k in _INIT_KEYS}
        loc = self._fit(frames, {**settings, "effects": settings.get("effects", ())})
        if loc is None:
            return None
        if self.scenario.walls and "effects" not in self.settings and self._shadowed(frames, loc):
            # fit the wall's attenuation too (mu is unidentifiable unless a line of sight crosses a wall);
            # warm start from the last walled estimate if there is one: the wall-free optimum is itself a
            # local optimum of the walled model (mu = 0), so starting only there never leaves it
            prev = next((e for e in reversed(self.estimates) if "wall_attenuation" in e["effects"]), None)
            init = ({k: prev[k] for k in _INIT_KEYS} if prev else
                    {**loc.sources_[0], "background_cps": loc.background_})
            walled = self._fit(frames, {**settings, "effects": ("wall_attenuation",), "init": init,
                                        "n_starts": max(settings.get("n_starts", 3), 5)})
            if walled is not None:  # even unconverged: sigma_m() then refuses to call it confident
                loc = walled
        self.localizer = loc
        converged = bool(getattr(loc, "info_", {}).get("converged", True))
        cov = repair_covariance(loc.covariance_)
        record = {"dwell": int(dwell), **loc.sources_[0], "background_cps": float(loc.background_),
                  "covariance": cov.tolist(), "sigma_m": sigma_m(cov, converged),
                  "effects": list(getattr(loc, "effects", ())), "converged": converged}
        self.estimates.append(record)
        return record

    def _fit(self, frames: Frames, settings: dict[str, Any]) -> Localizer | None:
        loc = make_localizer(self.method)
        loc.set_params(**{k: v for k, v in settings.items() if k in loc.get_params()})
        try:
            loc.fit(frames, self.scenario)
        except _FIT_ERRORS:
            return None
        return loc

    def _shadowed(self, frames: Frames, loc: Localizer) -> bool:
        """Does a recorded line of sight cross a mapped wall? Asked of every point within 1 m of the
        wall-free estimate, which a wall itself may have biased."""
        src = np.array([loc.sources_[0][k] for k in ("x", "y", "z")])
        around = src + np.array([[dx, dy, 0.0] for dx in (-1, 0, 1) for dy in (-1, 0, 1)])
        return bool(path_lengths(frames.positions[None, :, :], around[:, None, :], self.scenario.walls).max() > 0)
