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
   (warm-started from the last walled estimate) and keep the wall-free fit if that refit fails. A wall-free
   fit that fails its goodness of fit is refitted with the walls too, even unshadowed (a source behind a wall
   reads weak and the wall-free optimum flees the shadow), and the walled fit kept if its likelihood is higher. Once the
   last estimate was walled and its lines of sight still cross a wall, only the walled model is refitted. Every
   walled fit starts from the last estimate and the grid's best cells (:data:`WARM_WALLED_STARTS`), screened
   without pose offsets: a walled likelihood has a basin per shadow edge (a warm one's own basin alone while it
   is the best, escalating once on a misfit: :meth:`InflightEstimator._fit_walled`). A wall-free fit that
   fits and is not in a shadow is tested against the walled model (:meth:`InflightEstimator._walls_behind`);
5. second source: a one-source fit whose goodness-of-fit p is below :data:`SECOND_SOURCE_TRY_P`, or whose
   background stands :data:`BACKGROUND_EXCESS_Z` sd above the operator's (:func:`background_excess_z`: a far
   source's flux read as background fits well and biases the position), or a last estimate with two sources,
   is refitted with ``second_source`` and that fit kept when its likelihood-ratio test passes
   (:data:`SECOND_SOURCE_LR`); a first try is tested without pose offsets first and ends there if it fails (the
   offsets absorb part of what a second source explains, so that ratio bounds the profiled one); the record
   is the strongest source's, the other's position in ``params``;
6. repair the position covariance (non-finite -> 0, symmetrise, clip negative eigenvalues), scale it by the
   misfit factor (``estimator.modes.misfit_factor``: deviance per dof when above 1) and widen it to cover the
   likelihood's other modes over the search area (``estimator.modes.mode_covariance``; one-source fits): the
   fit's covariance is the curvature of the one mode it sits in, and lattice-clean after 4 dwells sat in a
   mirror mode 2.5 m off with a local 1-sigma of 0.149 m (now 2.1 m);
7. :func:`sigma_m`: the one definition of the estimate's 1-sigma; the record also carries the fit's
   goodness-of-fit ``p_value`` (below :data:`GOOD_FIT_P` the model misses something: :func:`gof_warning`).

At the end of the flight :meth:`InflightEstimator.finalize` adds to the final record, once, the
drift-aware bound ``bound_m`` (``estimator.localizers.mle.pose_aware_crlb`` for the flown frames and the
model the estimate used) and the 95 % ellipse ``ellipse_95`` (:func:`ellipse`). ``radseek run``'s
``summary.json`` and report, ``radseek replay`` and the benchmarks all read this one estimate.

``mission.search.SearchBrain`` calls it and only decides; ``radseek_cli.replay_cli`` calls it dwell by dwell
on a recorded flight and so reproduces the flown estimates.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy.special import chdtri, ndtri

from estimator.localizers.base import Localizer, make_localizer
from estimator.localizers.mle import covering_covariance
from estimator.mle import pooled
from estimator.modes import misfit_factor, mode_covariance
from radseek.dataset import Frames, Scenario
from radseek.geometry import path_lengths, semi_major_axis
from radseek.topics import ESTIMATE_BLOCK, ESTIMATE_STATE

__all__ = ["BACKGROUND_EXCESS_Z", "DEFAULT_LOCALIZER", "DEFAULT_SETTINGS", "ERROR_SIGMAS_FLAG", "GOOD_FIT_P",
           "MIN_SIGMA_M", "InflightEstimator", "background_excess_z", "bound_m", "drift_floor_m", "ellipse",
           "error_sigmas", "excess_warning", "gof_warning", "honest_covariance", "pose_sd_m", "repair_covariance",
           "sigma_m", "strength_order_z"]

DEFAULT_LOCALIZER = "mle"
#: in flight the estimate is refitted after every dwell: warm-started from the previous one (when the
#: localizer takes ``init``), with few extra starts and no CRLB, so the vehicle does not hover idle
DEFAULT_SETTINGS: Mapping[str, Any] = {"n_starts": 3, "compute_crlb": False}
MIN_FRAMES = 10  # frames recorded before the first fit is tried
POOL_FRAMES = 10  # frames pooled per chunk of a dwell (1 s at 10 Hz)
#: starts of every walled refit: the warm start and the grid's best cells, screened without pose offsets
#: (``estimator.mle._screen``) so that only the best basins are searched with them (the warm one alone when it
#: is still the best: ``warm_start``). A walled likelihood has a basin per shadow edge and new frames move which
#: is deepest: from the warm start alone, lattice-wall seed 0's dwell-5 refit stayed in dwell 4's basin
#: (half-deviance 180.7 there, 139.2 from a grid cell 0.4 m away) and the flight stopped 0.44 m off at 4.7 sigma
WARM_WALLED_STARTS = 5
#: m: a wall-free refit starts from the last estimate alone (grid starts only if it then misfits) when that
#: estimate fit well and its 1-sigma was below this: new frames move a confident optimum by decimetres, and the
#: grid starts cost 10x the warm one (outdoor seed 0, dwell 5: 69 MIGRAD calls warm, 1030 from a grid cell,
#: the same minimum)
WARM_SIGMA_M = 1.0
#: m: a smaller 1-sigma is a numerical artefact, not certainty (per-dwell pose offsets are centimetres)
MIN_SIGMA_M = 5e-3
_INIT_KEYS = ("x", "y", "cps_at_1m", "background_cps")
#: a fit whose goodness-of-fit p-value is below this misses a physical effect: ``localize``, ``run`` and
#: ``replay`` say so (:func:`gof_warning`)
GOOD_FIT_P = 1e-3
#: a second source is kept when 2 delta log L exceeds this: chi2 with 3 dof (its x, y and strength) at GOOD_FIT_P
SECOND_SOURCE_LR = float(chdtri(3, GOOD_FIT_P))
#: a walled fit replaces a wall-free one that fits and is not in a wall's shadow when 2 delta log L exceeds this:
#: chi2 with 1 dof (the wall's mu; the wall-free model is mu = 0) at GOOD_FIT_P
WALL_LR = float(chdtri(1, GOOD_FIT_P))
#: a one-source fit is tried against two below this goodness-of-fit p (the likelihood-ratio test above decides):
#: a weak second source read as background leaves p ~ 0.002 once the deviance is the profile's maximum (the
#: two-source scene: one-source fit 0.45 m off, background 80 cps against 30); fits that fit well rarely pay
SECOND_SOURCE_TRY_P = 0.01
#: the operator's pre-flight background (the scenario's ``background_cps``) is taken as known to this fraction (1 sd)
BACKGROUND_PRIOR_REL = 0.1
#: a fitted background this many sd above the operator's (:func:`background_excess_z`) may be a far source's flux:
#: it sends the second-source test (and the search a check dwell). The one-sided normal quantile at GOOD_FIT_P
#: (3.09). At 2.0, 177 instead of 162 of 200 two-source flights fitted the second source, but coverage was no better
#: (0.905 against 0.910), and dead time and anisotropy, which the in-flight model lacks, sent checks on 20 and 2
#: flights of their scenes (one false second source, one search ended misfit) against 1 and 0
BACKGROUND_EXCESS_Z = float(ndtri(1.0 - GOOD_FIT_P))
#: an estimate names another likelihood mode (``other_mode``) when that mode holds more than this share
OTHER_MODE_SHARE = 0.05
_BASE_PARAMS = ("x", "y", "z", "cps_at_1m", "background_cps")
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


def background_excess_z(fitted: float, error: float, prior: float) -> float:
    """How many sd the fitted background ``fitted`` (+- ``error``, the fit's) stands above the operator's
    pre-flight ``prior`` (known to :data:`BACKGROUND_PRIOR_REL`): (fitted - prior) / sqrt(error^2 + (rel prior)^2);
    nan when either is unknown. A one-source fit puts an unmodelled source's flux into the background: on the
    two-source scene (1300 cps 4.9 m from the 2200 cps source, 30 cps background) the information planner's
    one-source estimates read 45-62 cps, z 2.8-6.7, with goodness-of-fit p 0.1-0.9; on the default scene z
    was -1.4 to 1.2 (seeds 0-7). A prior of 0 (the dataset contract allows it) is no pre-flight value: nan."""
    if not float(prior) > 0:
        return math.nan
    scale = math.hypot(float(error), BACKGROUND_PRIOR_REL * float(prior))
    z = (float(fitted) - float(prior)) / scale if scale > 0 else math.nan
    return z if math.isfinite(z) else math.nan


def excess_warning(record: Mapping[str, Any], prior: float, dataset: Any = None) -> str | None:
    """The warning for a one-source estimate record (``effects``, ``background_cps``, ``background_excess_z``)
    whose background stands more than :data:`BACKGROUND_EXCESS_Z` sd above the operator's ``prior``, else None."""
    z = record.get("background_excess_z", math.nan)
    if "second_source" in (record.get("effects") or ()) or not (isinstance(z, int | float) and z > BACKGROUND_EXCESS_Z):
        return None
    where = f" {dataset}" if dataset else ""
    return (f"the fitted background {float(record['background_cps']):.0f} cps stands {z:.1f} sd above the operator's "
            f"{prior:g} cps: a source the model does not hold may be near, and its flux biases the position: run "
            f"`radseek diagnose{where}`")


def gof_warning(p_value: Any, dataset: Any = None) -> str | None:
    """The warning for a fit whose goodness of fit fails (p < :data:`GOOD_FIT_P`), else None."""
    try:
        p = float(p_value)
    except (TypeError, ValueError):
        return None
    if not p < GOOD_FIT_P:  # nan (no p-value) says nothing
        return None
    where = f" {dataset}" if dataset else ""
    return (f"goodness of fit p = {p:.2g} < {GOOD_FIT_P:g}: the model misses something here: "
            f"run `radseek diagnose{where}`")


def ellipse(covariance: Any, level: float = 0.95) -> dict[str, float]:
    """The ``level`` confidence ellipse of the x-y block of ``covariance``: semi-axes ``a_m`` >= ``b_m`` (m)
    and ``angle_deg`` of the major axis from +x (east), counter-clockwise. For a 2-D Gaussian the ellipse
    holding ``level`` of the probability is d^2 <= -2 ln(1 - level) (5.99 for 95 %)."""
    cov = np.asarray(covariance, dtype=float)[:2, :2]
    if not np.isfinite(cov).all():
        return {"a_m": math.inf, "b_m": math.inf, "angle_deg": 0.0}
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    k = -2.0 * math.log(1.0 - level)
    a, b = (math.sqrt(k * max(float(x), 0.0)) for x in (w[1], w[0]))
    angle = math.degrees(math.atan2(v[1, 1], v[0, 1]))
    return {"a_m": a, "b_m": b, "angle_deg": (angle + 90.0) % 180.0 - 90.0}


def drift_floor_m(crlb_pose: Any) -> float:
    """The 1-sigma the drift alone allows: semi-major axis of the x-y block of the drift-aware bound
    (``crlb_pose_`` of the fit: pose offsets as nuisances under their random-walk prior), nan without one.
    An estimate whose ``sigma_m`` sits at this floor and has stopped falling is drift-limited: more dwells
    add metres (drift) about as fast as they add counts."""
    if crlb_pose is None:
        return math.nan
    c = np.asarray(crlb_pose, dtype=float)[:2, :2]
    return semi_major_axis(c) if np.isfinite(c).all() else math.nan


def pose_sd_m(frames: Frames) -> float:
    """The largest horizontal pose standard deviation the vehicle reported over ``frames`` (m): the size of
    the odometry drift so far, which a drift floor (:func:`drift_floor_m`) cannot much exceed; one that does
    is a floor of the geometry (counts), not of the drift."""
    if len(frames) == 0:
        return math.nan
    return float(math.sqrt(max(float(np.max(frames.var_x)), float(np.max(frames.var_y)), 0.0)))


def bound_m(crlb_xy: Any) -> float:
    """The bound as a distance: the rms horizontal error an unbiased estimate can reach, sqrt(trace) of the
    x-y block of a Cramér-Rao bound (as ``radseek localize`` reports it)."""
    c = np.asarray(crlb_xy, dtype=float)[:2, :2]
    return float(math.sqrt(max(float(np.trace(c)), 0.0))) if np.isfinite(c).all() else math.inf


def repair_covariance(covariance: Any) -> np.ndarray:
    """The (3, 3) position block of a fit's covariance made a covariance: non-finite entries 0,
    symmetric, negative eigenvalues (round-off of a nearly singular Fisher inverse) clipped to 0."""
    cov = np.asarray(covariance, dtype=float)[:3, :3]
    cov = np.where(np.isfinite(cov), cov, 0.0)
    cov = 0.5 * (cov + cov.T)
    w, v = np.linalg.eigh(cov)
    return (v * np.clip(w, 0, None)) @ v.T


def honest_covariance(scenario: Scenario, frames: Frames, source: Mapping[str, Any], local: np.ndarray,
                      check: bool = True, phi: float = 1.0) -> tuple[np.ndarray, dict[str, float] | None]:
    """The covariance to report: the fit's local one (drift-aware, already times the misfit factor ``phi``)
    widened to cover the likelihood's other modes over the search area (``estimator.modes``, when ``check``: a
    trustworthy one-source fit; ``source`` has ``x``, ``y``, ``z`` and the fit's ``params``), and the best other
    mode when it holds more than :data:`OTHER_MODE_SHARE` of the probability (``x``, ``y``, ``delta_nll`` above
    the estimate's, ``share``), else None."""
    local = np.asarray(local, dtype=float)
    if not check or not math.isfinite(sigma_m(local)):
        return local, None
    try:
        m = mode_covariance(scenario, frames, dict(source), local, phi)
    except _FIT_ERRORS:
        return local, None
    cov = local.copy()
    cov[:2, :2] = covering_covariance(local[:2, :2], m.covariance)
    other = None if not m.far_share > OTHER_MODE_SHARE else \
        {"x": m.best_x, "y": m.best_y, "delta_nll": m.best_delta, "share": m.far_share}
    return cov, other


def error_sigmas(covariance: Any, dx: float, dy: float) -> float:
    """How many 1-sigmas an error (``dx``, ``dy``) lies outside the x-y ellipse of ``covariance``: its
    Mahalanobis distance (inf for an untrustworthy or degenerate covariance)."""
    c = np.asarray(covariance, dtype=float)[:2, :2]
    if not np.isfinite(c).all():
        return math.inf
    e = np.array([dx, dy])
    try:
        return float(math.sqrt(max(float(e @ np.linalg.solve(c, e)), 0.0)))
    except np.linalg.LinAlgError:
        return math.inf


#: an error vs truth more than this many 1-sigmas outside the ellipse is flagged: chi2 with 2 dof at GOOD_FIT_P
ERROR_SIGMAS_FLAG = float(math.sqrt(chdtri(2, GOOD_FIT_P)))


class InflightEstimator:
    """Feed it the frames recorded so far after each dwell; it returns the estimate record (or None).

    ``estimates`` is its history, one record per successful fit; ``localizer`` the last fitted localizer
    (for publishing the full ``estimate`` message). A record has ``dwell`` (the caller's dwell count),
    ``x``, ``y``, ``z`` (m), ``cps_at_1m``, ``background_cps`` (cps), ``covariance`` ((3, 3) position
    covariance in m^2, repaired, misfit-scaled and covering the other modes, as nested lists), ``sigma_m``
    (:func:`sigma_m` of it), ``sigma_local_m`` (the fit's own curvature alone), ``misfit_factor``,
    ``other_mode`` (the best other likelihood mode when it holds over :data:`OTHER_MODE_SHARE`, else None),
    ``effects`` (the fitted
    model's), ``params`` (the fitted effects' parameters, e.g. ``wall_attenuation.mu_per_m``), ``converged``
    ``p_value`` (goodness of fit, nan if the localizer reports none), ``drift_floor_m``
    (:func:`drift_floor_m`), ``pose_sd_m`` (:func:`pose_sd_m`), ``background_excess_z``
    (:func:`background_excess_z`) and ``strength_order_z`` (:func:`strength_order_z`; nan with one source).
    :meth:`finalize` adds ``bound_m``
    and ``ellipse_95`` to the last record.
    """

    def __init__(self, scenario: Scenario, localizer: str = DEFAULT_LOCALIZER,
                 settings: Mapping[str, Any] | None = None):
        self.scenario = scenario
        self.method = localizer
        self.settings = dict(DEFAULT_SETTINGS if settings is None else settings)
        self.estimates: list[dict[str, Any]] = []
        self.localizer: Localizer | None = None
        self._frames: Frames | None = None  # the (pooled) frames of the last record
        self._primary = 0  # which fitted source the last record is (the strongest)

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
            settings["init"] = _warm_init(self.estimates[-1])
        walls = bool(self.scenario.walls) and "effects" not in self.settings
        last = self.estimates[-1] if self.estimates else None
        loc = None
        if walls and last is not None and self._shadowed(frames, [last[k] for k in ("x", "y", "z")]):
            walled_settings = {**settings, "effects": ("wall_attenuation",)}
            if "wall_attenuation" in last["effects"]:
                # the walls mattered at the last estimate and still do: refit the walled model straight from it
                # and the grid's best cells, without the wall-free fit first
                loc = self._fit_walled(frames, walled_settings, warm=not last["p_value"] < GOOD_FIT_P)
            else:
                # a recorded line of sight near the last (wall-free) estimate now crosses a wall: the walled
                # model and its starts from it, without a wall-free fit first that the shadow would discard
                # (lattice-wall seed 3, dwell 5: 0.3 s of a 0.9 s refit)
                loc = self._fit(frames, {**walled_settings, "n_starts": WARM_WALLED_STARTS})
            if loc is not None:
                loc = self._wall_free_if_enough(frames, settings, loc)
        if loc is None:
            plain = {**settings, "effects": settings.get("effects", ())}
            # with mapped walls a misfit goes on to the walled fit and its starts, not to the wall-free starts
            loc = self._fit_warm(frames, plain, escalate=not walls) if _confident(last) else self._fit(frames, plain)
            if loc is None:
                return None
            shadowed = walls and self._shadowed(frames, [loc.sources_[0][k] for k in ("x", "y", "z")])
            if walls and (shadowed or _misfit(loc)):
                # fit the wall's attenuation too (mu is unidentifiable unless a line of sight crosses a wall);
                # warm start from the last walled estimate if there is one: the wall-free optimum is itself a
                # local optimum of the walled model (mu = 0), so starting only there never leaves it
                prev = next((e for e in reversed(self.estimates) if "wall_attenuation" in e["effects"]), None)
                init = (_warm_init(prev) if prev else
                        {**loc.sources_[0], "background_cps": loc.background_})
                walled = self._fit_walled(frames, {**settings, "effects": ("wall_attenuation",), "init": init},
                                          warm=prev is not None and not prev["p_value"] < GOOD_FIT_P)
                # even unconverged: sigma_m() then refuses to call it confident. A wall-free fit that fails
                # its goodness of fit with no recorded line of sight near it crossing a wall may have fled
                # the shadow (a source behind a wall reads weak, so the wall-free optimum moves away): then
                # the walled model is kept only if it explains the counts better. In a shadow it is kept when the
                # wall-free fit misfits or the walls' likelihood-ratio test passes (a mapped wall need not
                # attenuate: _wall_free_if_enough)
                if walled is not None and (_walls_needed(loc, walled) if shadowed
                                           else walled.info_["nll"] < loc.info_["nll"]):
                    loc = walled
            elif walls:
                loc = self._walls_behind(frames, settings, loc)
        if "effects" not in self.settings and "wall_attenuation" not in getattr(loc, "effects", ()):
            loc = self._second_source(frames, settings, loc, last)
        self.localizer = loc
        self._frames = frames
        info = getattr(loc, "info_", {})
        converged = bool(info.get("converged", True))
        k = self._primary = _primary(loc)
        local = repair_covariance(_block(loc.covariance_, k))
        params = {n: float(v) for n, v in info.get("values", {}).items() if n not in _BASE_PARAMS}
        if k:  # the second source is the stronger: the record's source is it, its params name the other
            params.update({f"second_source.{n}": float(v) for n, v in loc.sources_[0].items()})
        phi = misfit_factor(info.get("deviance_per_dof"))
        cov, modes = honest_covariance(self.scenario, frames, {**loc.sources_[k], "params": params}, local * phi,
                                       converged and "second_source" not in getattr(loc, "effects", ()), phi)
        record = {"dwell": int(dwell), **loc.sources_[k], "background_cps": float(loc.background_),
                  "covariance": cov.tolist(), "sigma_m": sigma_m(cov, converged),
                  "sigma_local_m": sigma_m(local, converged), "misfit_factor": phi, "other_mode": modes,
                  "effects": list(getattr(loc, "effects", ())), "params": params,
                  "converged": converged, "p_value": float(info.get("p_value", math.nan)),
                  "drift_floor_m": drift_floor_m(_block(getattr(loc, "crlb_pose_", None), k)),
                  "pose_sd_m": pose_sd_m(frames), "background_excess_z": self._excess_z(loc),
                  "strength_order_z": strength_order_z(loc, k)}
        self.estimates.append(record)
        return record

    def message(self, t: float) -> Any:
        """The zenoh ``estimate`` of the last record (None before one): the localizer's (``to_estimate``), with the
        record's source's position block replaced by the record's covariance, the one the search decides on and
        the summary reports (misfit-scaled, covering the likelihood's other modes: :func:`honest_covariance`). The
        localizer's own block is the fit's curvature alone: a flight whose likelihood had a second mode as good
        showed "sigma 0.10 m" live while its decision read 1.37 m. Its cross terms with the strength are kept
        when the block stays a covariance (the record's covers the fit's), else dropped."""
        if self.localizer is None or not self.estimates:
            return None
        msg = self.localizer.to_estimate(t)
        k, n = self._primary, len(ESTIMATE_STATE)
        block = np.array(msg.covariance[ESTIMATE_BLOCK * k:ESTIMATE_BLOCK * (k + 1)], dtype=float).reshape(n, n)
        honest = np.array(self.estimates[-1]["covariance"], dtype=float)
        if not np.isfinite(honest).all():
            return msg
        own_known = np.isfinite(block).all()
        block[:3, :3] = honest
        if not own_known:
            # an unconverged fit has no Hessian (NaN): its cross terms with the strength stay unknown (outdoor
            # seed 14 of a 400-seed campaign: eigvalsh of the NaN block raised and ended the flight)
            block[:3, 3] = block[3, :3] = math.nan
        elif np.linalg.eigvalsh(0.5 * (block + block.T)).min() < -1e-12 * max(float(np.abs(block).max()), 1e-300):
            block[:3, 3] = block[3, :3] = 0.0
        msg.covariance[ESTIMATE_BLOCK * k:ESTIMATE_BLOCK * (k + 1)] = block.ravel().tolist()
        msg.validate()
        return msg

    def other_source(self) -> dict[str, Any] | None:
        """The last fit's other source when it has two (the one the record is not): ``x``, ``y``, ``z``,
        ``cps_at_1m``, ``covariance`` (its (3, 3) position block, repaired as the record's) and ``cps_sd`` (its
        strength's sd, nan if unknown), with the record's own ``cps_sd`` as ``reported_cps_sd``; else None."""
        loc = self.localizer
        if loc is None or len(getattr(loc, "sources_", ())) != 2:
            return None
        k, o = self._primary, 1 - self._primary
        sd = np.sqrt(np.abs(np.diag(np.asarray(loc.covariance_, dtype=float))))
        return {**loc.sources_[o], "covariance": repair_covariance(_block(loc.covariance_, o))[:3, :3],
                "cps_sd": float(sd[4 * o + 3]), "reported_cps_sd": float(sd[4 * k + 3])}

    def _wall_free_if_enough(self, frames: Frames, settings: dict[str, Any], walled: Localizer) -> Localizer:
        """A walled fit made because a line of sight crosses a mapped wall, against the wall-free model it nests
        (mu = 0), refitted warm from it: the wall-free fit is kept when it fits and the walls do not explain the
        counts better by :data:`WALL_LR` (:func:`_walls_needed`). A mapped wall need not attenuate (outdoor maps
        restricted areas as walls; its world has no wall effect), and the walled fit profiles the pose offsets by
        two chord steps, which near a strong source is not the profile's maximum: outdoor seed 76 ended at mu =
        5e-6 /m, 1.7 nats worse than the wall-free fit and 0.18 m from it (0.55 m off at 3.6 sigma). Re-drawn
        drift on its flight: walled fits covered 89 % (100 draws), wall-free fits of the same frames 95 %."""
        init = {**walled.sources_[0], "background_cps": walled.background_}
        plain = self._fit(frames, {**settings, "effects": (), "init": init, "n_starts": 1})
        return walled if plain is None or _walls_needed(plain, walled) else plain

    def _second_source(self, frames: Frames, settings: dict[str, Any], loc: Localizer,
                       last: Mapping[str, Any] | None) -> Localizer:
        """A one-source fit that fails its goodness of fit (or a last estimate that had two sources) is
        refitted with ``second_source`` (warm-started from the last two-source estimate if any); the
        two-source fit is kept when its likelihood-ratio test against one source passes at ``GOOD_FIT_P``
        (2 delta log L > chi2_3 quantile: x, y, strength of the second source)."""
        two = last is not None and "second_source" in last["effects"]
        if not (two or _misfit(loc, SECOND_SOURCE_TRY_P) or self._excess_z(loc) > BACKGROUND_EXCESS_Z):
            return loc
        init = dict(settings.get("init") or {})
        if not two:
            # tested without pose offsets first: a try that fails there ends (outdoor seed 6, dwell 5: 1.5 s, 1.1 s
            # of it a profiled search crawling 407 calls through a two-source fit that explained nothing more)
            return self._nested_test(frames, settings, loc, ("second_source",), init or None, 1, SECOND_SOURCE_LR)
        init.update({n: v for n, v in last["params"].items() if n.startswith("second_source.")})
        cand = self._fit(frames, {**settings, "effects": ("second_source",), "init": init,
                                  "n_starts": max(settings.get("n_starts", 3), 5)})
        if cand is not None and 2.0 * (loc.info_["nll"] - cand.info_["nll"]) > SECOND_SOURCE_LR:
            return cand
        return loc

    def _excess_z(self, loc: Localizer) -> float:
        """:func:`background_excess_z` of a fit against the scenario's background (nan without the fit's error)."""
        info = getattr(loc, "info_", {})
        return background_excess_z(loc.background_, info.get("errors", {}).get("background_cps", math.nan),
                                   self.scenario.background_cps)

    def _walls_behind(self, frames: Frames, settings: dict[str, Any], loc: Localizer) -> Localizer:
        """A wall-free fit that fits and that no recorded line of sight near it crosses a wall may still have fled
        a shadow: a source behind a wall reads weak, and a weaker source elsewhere explains that well (lattice-wall
        seeds 57 and 152: 1.7 and 2.6 m off at p = 0.05 and 0.69, searches stopped there). The walled model
        nests it (mu = 0): :meth:`_nested_test` with one dof (mu, :data:`WALL_LR`; those flights: 27 and 13
        already at their fourth dwell), its starts the grid's cells. Asked first of the start grid alone
        (``estimator.mle.wall_grid_ratio``, no search): below half the threshold there the test is not run. On
        outdoor, whose shed and tank pad are mapped as walls, the grid ratio was 0.0 at every refit, and the test
        had doubled the CPU per search (1.5 -> 3.5 s) and put 2 of 56 refits over 1 s; on lattice-wall it read
        3-39 where the test read 5-30."""
        from estimator.localizers.mle import MaximumLikelihood
        from estimator.mle import wall_grid_ratio

        walled = MaximumLikelihood(effects=("wall_attenuation",)).model_for(self.scenario)
        if wall_grid_ratio(walled, frames) < WALL_LR / 2:
            return loc
        return self._nested_test(frames, settings, loc, ("wall_attenuation",), None, WARM_WALLED_STARTS - 1, WALL_LR)

    def _nested_test(self, frames: Frames, settings: dict[str, Any], loc: Localizer, effects: tuple[str, ...],
                     init: Mapping[str, float] | None, n_starts: int, threshold: float) -> Localizer:
        """The wall-free one-source fit ``loc`` against the model with ``effects``, which nests it: the richer
        fit replaces it when 2 delta log L exceeds ``threshold``. Tested without pose offsets first (one model
        evaluation a call, not eight; from ``init`` and ``n_starts``): the offsets absorb part of what the richer
        model explains, so the ratio there bounds the profiled one (second source, 8 of 8 tries on two-source
        and outdoor seeds: profiled 0-1284 against 0-2316). Only a pass runs the profiled fit, from the optimum
        found there."""
        plain = {**settings, "pose_uncertainty": False, "n_starts": 1}
        base = self._fit(frames, {**plain, "effects": (), "init": {**loc.sources_[0],
                                                                    "background_cps": loc.background_}})
        rich = self._fit(frames, {**plain, "effects": effects, "init": init, "n_starts": n_starts})
        if base is None or rich is None or not 2.0 * (base.info_["nll"] - rich.info_["nll"]) > threshold:
            return loc
        cand = self._fit(frames, {**settings, "effects": effects, "init": dict(rich.info_["values"]), "n_starts": 1})
        if cand is not None and 2.0 * (loc.info_["nll"] - cand.info_["nll"]) > threshold:
            return cand
        return loc

    def finalize(self) -> dict[str, Any] | None:
        """The flight ended: add ``bound_m`` and ``ellipse_95`` to the final record (once) and return it."""
        est = self.estimate
        if est is None or "bound_m" in est:
            return est
        # an estimate that is not trustworthy (sigma_m inf) has no finite ellipse either
        est["ellipse_95"] = ellipse(est["covariance"] if math.isfinite(est["sigma_m"]) else np.full((2, 2), np.nan))
        # the fit computed it for its covariance already
        hybrid = _block(getattr(self.localizer, "crlb_pose_", None), self._primary)
        if hybrid is not None:
            est["bound_m"] = bound_m(hybrid)
        else:
            est["bound_m"] = flown_bound(self.scenario, self._frames, est, self.method, self.settings) \
                if self._frames is not None else math.nan
        return est

    def _fit(self, frames: Frames, settings: dict[str, Any]) -> Localizer | None:
        loc = make_localizer(self.method)
        loc.set_params(**{k: v for k, v in settings.items() if k in loc.get_params()})
        try:
            loc.fit(frames, self.scenario)
        except _FIT_ERRORS:
            return None
        return loc

    def _fit_warm(self, frames: Frames, settings: dict[str, Any], escalate: bool = True) -> Localizer | None:
        """:meth:`_fit` from the warm start alone, and with all ``n_starts`` only if that fit fails (no
        result, or, when ``escalate``, its goodness of fit fails): between dwells the optimum moves by
        decimetres, and the grid starts only find a better minimum when the warm one no longer explains the
        counts. Wall-free refits only: without ``escalate`` (the scene maps walls) a misfit is kept here and goes
        on to the walled fit and its starts instead (walled refits: :meth:`_fit_walled`)."""
        loc = self._fit(frames, {**settings, "n_starts": 1})
        if loc is not None and not (escalate and _misfit(loc)):
            return loc
        return self._fit(frames, settings)

    def _fit_walled(self, frames: Frames, settings: dict[str, Any], warm: bool) -> Localizer | None:
        """The walled model from ``settings["init"]`` and the grid's best cells (:data:`WARM_WALLED_STARTS`).
        ``warm`` (the init is a walled estimate that fit): its basin goes on alone when the screen finds it the
        best (``warm_start``), and the best two basins only if that fit fails or misfits; the better of the two
        fits is kept. Without that escalation lattice-wall seeds 321 and 370 kept a misfit basin (p = 7e-28) to
        the end of the dwell budget."""
        settings = {**settings, "n_starts": WARM_WALLED_STARTS}
        loc = self._fit(frames, {**settings, "warm_start": True}) if warm else None
        if loc is not None and not _misfit(loc):
            return loc
        full = self._fit(frames, settings)
        fits = [f for f in (loc, full) if f is not None]
        return min(fits, key=lambda f: f.info_["nll"]) if fits else None

    def _shadowed(self, frames: Frames, source: Any) -> bool:
        """Does a recorded line of sight cross a mapped wall? Asked of every point within 1 m of the
        estimate ``source`` (x, y, z), which a wall itself may have biased."""
        src = np.asarray(source, dtype=float)
        around = src + np.array([[dx, dy, 0.0] for dx in (-1, 0, 1) for dy in (-1, 0, 1)])
        return bool(path_lengths(frames.positions[None, :, :], around[:, None, :], self.scenario.walls).max() > 0)


def _warm_init(record: Mapping[str, Any]) -> dict[str, float]:
    """A refit's warm start from an estimate record: its source, background and every other parameter it fitted
    (``params``: a wall's mu, a second source; a model without them ignores them), so a walled refit starts at
    the fitted mu rather than the model's default."""
    return {**{k: float(v) for k, v in record.get("params", {}).items()}, **{k: record[k] for k in _INIT_KEYS}}


def _primary(loc: Localizer) -> int:
    """Index of the strongest fitted source: the one the search locates."""
    return int(np.argmax([src["cps_at_1m"] for src in loc.sources_]))


def strength_order_z(loc: Localizer, k: int) -> float:
    """How many sd source ``k``'s fitted strength stands above the other's in a two-source fit: the difference
    over its sd from the fit's covariance (cross term included); nan with one source or no finite covariance.
    Below ~2 the counts have not decided which source is the stronger, so which one the record is."""
    sources = getattr(loc, "sources_", ())
    cov = getattr(loc, "covariance_", None)
    if len(sources) != 2 or cov is None:
        return math.nan
    c = np.asarray(cov, dtype=float)
    i, j = 4 * k + 3, 4 * (1 - k) + 3
    var = c[i, i] + c[j, j] - 2.0 * c[i, j]
    diff = sources[k]["cps_at_1m"] - sources[1 - k]["cps_at_1m"]
    return float(diff / math.sqrt(var)) if math.isfinite(var) and var > 0 else math.nan


def _block(matrix: Any, k: int) -> Any:
    """Source ``k``'s (4, 4) block of a (4M, 4M) per-source matrix (None stays None)."""
    if matrix is None:
        return None
    return np.asarray(matrix, dtype=float)[4 * k:4 * k + 4, 4 * k:4 * k + 4]


def _confident(record: Mapping[str, Any] | None) -> bool:
    """A last estimate a refit may start from alone: converged, fit well, 1-sigma below :data:`WARM_SIGMA_M`."""
    return (record is not None and record["converged"] and not record["p_value"] < GOOD_FIT_P
            and record["sigma_m"] < WARM_SIGMA_M)


def _walls_needed(plain: Localizer, walled: Localizer) -> bool:
    """Keep the walled fit over the wall-free one it nests: the wall-free fit fails its goodness of fit, or the
    walls' likelihood-ratio test passes (2 delta log L > :data:`WALL_LR`, one dof: mu), as for an unshadowed fit
    (:meth:`InflightEstimator._walls_behind`)."""
    return _misfit(plain) or 2.0 * (plain.info_["nll"] - walled.info_["nll"]) > WALL_LR


def _misfit(loc: Localizer, level: float = GOOD_FIT_P) -> bool:
    """The fit's goodness of fit fails (p < ``level``, :data:`GOOD_FIT_P` by default; no p-value: not known to
    fail)."""
    return bool(getattr(loc, "info_", {}).get("p_value", 1.0) < level)


def flown_bound(scenario: Scenario, frames: Frames, record: Mapping[str, Any], localizer: str = DEFAULT_LOCALIZER,
                settings: Mapping[str, Any] | None = None) -> float:
    """:func:`bound_m` of the drift-aware bound (``pose_aware_crlb``: random-walk prior on the pose
    offsets, as the fit) at the estimate ``record`` for ``frames`` (pooled as in flight: pass
    ``pooled(frames, POOL_FRAMES, dwells_only=True)`` for recorded frames), with the model the
    estimate used (its ``effects`` and fitted ``params``); nan if it cannot be computed (another localizer)."""
    from estimator.localizers.mle import MaximumLikelihood, pose_aware_crlb

    if localizer != "mle":
        return math.nan
    loc = MaximumLikelihood(effects=tuple(record.get("effects", ())))
    loc.set_params(**{k: v for k, v in (settings or {}).items()
                      if k in loc.get_params() and k not in ("effects", "init", "n_starts", "compute_crlb")})
    model = loc.model_for(scenario)
    theta = {k: float(record[k]) for k in ("x", "y", "z", "cps_at_1m", "background_cps")}
    theta.update({k: float(v) for k, v in record.get("params", {}).items() if k in model.param_names})
    theta = {k: v for k, v in theta.items() if k in model.param_names}
    try:
        c = pose_aware_crlb(model, theta, frames)
    except _FIT_ERRORS:
        return math.nan
    names = model.free_names
    ix, iy = names.index("x"), names.index("y")
    return bound_m(c[np.ix_([ix, iy], [ix, iy])])

