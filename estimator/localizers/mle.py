"""Poisson maximum likelihood as a localizer: wraps :func:`estimator.mle.fit` and :func:`estimator.mle.crlb`.

The model is :class:`estimator.model.MeasurementModel` with the chosen ``effects`` (any subset of the
effect vocabulary except ``gain_drift``): per-frame total counts n_i ~ Poisson(mu_i(theta)), maximised
multi-start and bounded (MIGRAD), with the per-dwell pose offsets profiled out when
``pose_uncertainty``. ``covariance_`` is the inverse Hessian of the negative log-likelihood (observed
information, HESSE), widened where needed to cover the drift-aware expected-information bound
(:func:`covering_covariance`, :func:`pose_aware_crlb`); with mapped walls in the model it is that bound alone;
``crlb_`` is the Cramér-Rao bound for the flown
poses at the estimate: paper 004
eq. 5.3-5.7 generalised to the Poisson likelihood and the model's free parameters (J = sum_i grad mu_i
grad mu_i^T / mu_i), inverted over all free parameters and then restricted to (x, y, z, cps_at_1m) per
source (so nuisance parameters such as the background are accounted for, not ignored). That bound takes
the recorded poses as exact; ``crlb_pose_`` (same layout) also treats each dwell's pose offset as a
nuisance with the dataset's reported variance (:func:`pose_aware_crlb`), which is the bound an estimator
using uncertain poses can actually reach.

A ``second_source`` effect gives a second entry in ``sources_``. ``fixed`` pins parameters at given
values (e.g. ``{"dead_time.tau_s": 1.2e-5}`` for a calibrated detector). ``energy_window_keV=(lo, hi)``
fits only the counts of the channels overlapping that window (e.g. the Cs-137 photopeak, 600-720 keV);
``cps_at_1m`` is then the window's rate at 1 m.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from estimator.localizers.base import Localizer, source_dict
from radseek.dataset import Frames, Scenario

__all__ = ["MaximumLikelihood", "covering_covariance", "source_param_names", "pose_aware_crlb"]

SOURCE_KEYS = ("x", "y", "z", "cps_at_1m")


def source_param_names(effects: Sequence[str]) -> list[list[str]]:
    """Model parameter names of (x, y, z, cps_at_1m) for each source the model has."""
    out = [list(SOURCE_KEYS)]
    if "second_source" in effects:
        out.append([f"second_source.{k}" for k in SOURCE_KEYS])
    return out


def _embed(mat: np.ndarray, names: list[str], per_source: list[list[str]]) -> np.ndarray:
    """(4M x 4M) over (x, y, z, cps_at_1m) per source from a (k x k) matrix over ``names`` (fixed -> 0)."""
    flat = [n for src in per_source for n in src]
    out = np.zeros((len(flat), len(flat)))
    pos = {n: i for i, n in enumerate(names)}
    idx = [(i, pos[n]) for i, n in enumerate(flat) if n in pos]
    for a, pa in idx:
        for b, pb in idx:
            out[a, b] = mat[pa, pb]
    return out


def pose_aware_crlb(model, theta: dict[str, float], frames: Frames, landmarks: bool = False) -> np.ndarray:
    """Hybrid Cramér-Rao bound of the free parameters when the pose offsets are unknowns with their prior.

    The Poisson CRLB (:func:`estimator.mle.crlb`) takes the recorded poses as exact. With the offsets of
    :class:`estimator.mle.PoseGroups` as nuisance parameters with Gaussian prior precision Sigma^-1 (a random
    walk in distance flown for odometry drift, independent per dwell otherwise), the hybrid information is
    [[J_tt, J_td], [J_dt, J_dd + Sigma^-1]] (Bayesian in the offsets, van Trees; Fisher in theta) and the
    bound on theta is the inverse of its Schur complement J_tt - J_td (J_dd + Sigma^-1)^-1 J_dt.

    ``landmarks=False`` (the default) takes a pose offset to move the whole measured world with the
    vehicle: its count derivative is minus the derivative with respect to the source position(s), so a
    mapped wall does not tell the drift. With ``landmarks=True`` the offset moves the detector alone and a
    wall's shadow edge pins the pose in the wall's frame; that information exists, but at a hard edge the
    likelihood is kinked and the fit does not reach it (lattice-wall: the source error follows the drift,
    0.09 m against a 0.02 m landmark bound, 0.004 m with the true poses). For translation-invariant
    models (no walls) the two are the same.
    """
    from estimator.mle import PoseGroups, declared_pose_error, expected_count_gradient, offset_jacobian

    full = {**model.defaults(), **theta}
    mu = np.maximum(model.expected_counts(full, frames), 1e-12)
    gt = expected_count_gradient(model, full, frames)  # (N, k)
    j = (gt / mu[:, None]).T @ gt
    groups = PoseGroups.from_frames(frames, declared_pose_error(model))
    if not groups.active.any():
        return np.linalg.pinv(j)
    if landmarks:
        gd = offset_jacobian(model, full, frames, mu, central=True)  # (N, 3)
    else:
        gd = -translation_gradient(model, full, frames)
    gd[:, ~groups.active] = 0.0
    jdd = groups.group_sum(gd[:, :, None] * gd[:, None, :] / mu[:, None, None])
    jdt = groups.group_sum(gd[:, :, None] * (gt / mu[:, None])[:, None, :])  # (G, 3, k)
    x = groups.solve(jdd, jdt)  # (J_dd + Sigma^-1)^-1 J_dt
    j = j - np.einsum("gak,gal->kl", jdt, x)
    return np.linalg.pinv(j)


def translation_gradient(model, theta: dict[str, float], frames: Frames) -> np.ndarray:
    """d mu_i / d t (N, 3) for a translation t of every source together (walls fixed)."""
    from estimator.mle import expected_count_gradient

    per_source = source_param_names(model.effects)
    names = [src[:3] for src in per_source]  # (x, y, z) of each source
    g = expected_count_gradient(model, theta, frames, names=[n for xyz in names for n in xyz])
    return g.reshape(len(frames), len(names), 3).sum(axis=1)


def covering_covariance(observed: np.ndarray, expected: np.ndarray) -> np.ndarray:
    """The smallest-change covariance that covers both: ``expected + P+(observed - expected)``, P+ keeping
    the positive eigen-part, so its ellipse holds both ellipses (Loewner order: >= each of them).

    ``observed`` is the inverse Hessian of the fit (HESSE, observed information); ``expected`` the inverse
    expected information with the pose offsets as nuisances under their drift prior (:func:`pose_aware_crlb`).
    The expected information caps what one pose group can tell by its drift prior, so the reported uncertainty
    never claims more than the drift allows. Wall-free fits report this cover; a walled fit reports ``expected``
    alone (:meth:`MaximumLikelihood._fit`: at the walls' shadow edges the likelihood is not quadratic and the
    numerical Hessian errs both ways). A non-finite ``observed`` (a fit that did not converge) stays
    non-finite: no ellipse is claimed for it."""
    observed = np.asarray(observed, dtype=float)
    expected = np.asarray(expected, dtype=float)
    if not (np.isfinite(observed).all() and np.isfinite(expected).all()):
        return observed
    diff = 0.5 * ((observed - expected) + (observed - expected).T)
    w, v = np.linalg.eigh(diff)
    return 0.5 * (expected + expected.T) + (v * np.clip(w, 0.0, None)) @ v.T


class MaximumLikelihood(Localizer):
    """Poisson MLE with Fisher covariance and CRLB (see module docstring)."""

    name = "mle"

    def __init__(self, effects: Sequence[str] = (), n_starts: int = 8, seed: int = 0, pose_uncertainty: bool = True,
                 fixed: Mapping[str, float] | None = None, init: Mapping[str, float] | None = None,
                 compute_crlb: bool = True, energy_window_keV: Sequence[float] | None = None,
                 warm_start: bool = False):
        self.effects = effects
        self.n_starts = n_starts
        self.seed = seed
        self.pose_uncertainty = pose_uncertainty
        self.fixed = fixed
        self.init = init
        self.warm_start = warm_start
        self.compute_crlb = compute_crlb
        self.energy_window_keV = energy_window_keV

    def model_for(self, scenario: Scenario):
        from estimator.model import MeasurementModel

        channels = None
        if self.energy_window_keV is not None:
            lo, hi = self.energy_window_keV
            channels = MeasurementModel.window_channels(scenario, float(lo), float(hi))
        model = MeasurementModel(scenario, effects=tuple(self.effects), channels=channels)
        if self.fixed:
            model = model.with_params(**{k: {"value": float(v), "fixed": True} for k, v in self.fixed.items()})
        return model

    def _fit(self, frames: Frames, scenario: Scenario) -> None:
        from estimator.mle import crlb, fit

        model = self.model_for(scenario)
        res = fit(model, frames, n_starts=self.n_starts, seed=self.seed, pose_uncertainty=self.pose_uncertainty,
                  init=dict(self.init) if self.init else None, warm_start=self.warm_start)
        per_source = source_param_names(model.effects)
        self.result_ = res
        self.sources_ = [source_dict(*(res.values[n] for n in names)) for names in per_source]
        cov = np.asarray(res.covariance, dtype=float)
        hybrid = None
        if self.pose_uncertainty and np.any(frames.pose_variances > 0) and list(res.free_names) == model.free_names:
            hybrid = pose_aware_crlb(model, res.values, frames)
            # a walled likelihood is not quadratic at its optimum (the walls' shadow-edge ramps), and its
            # numerical Hessian errs both ways: alone it covered 74 % of lattice-wall searches, as the cover of
            # the bound it reported 0.1-0.4 m on flights 0.01-0.05 m off and 16 % never stopped. The expected
            # information (the average curvature) alone covers 95.5 % and every search stops found
            walled = "wall_attenuation" in model.effects and bool(scenario.walls)
            cov = hybrid if walled and np.isfinite(cov).all() else covering_covariance(cov, hybrid)
        self.covariance_ = _embed(cov, res.free_names, per_source)
        self.background_ = float(res.values["background_cps"])
        self.crlb_ = None
        self.crlb_pose_ = None if hybrid is None else _embed(hybrid, model.free_names, per_source)
        if self.compute_crlb:
            c = crlb(model, res.values, frames)
            self.crlb_ = _embed(c, model.free_names, per_source)
            self.crlb_full_ = c
        self.info_: dict[str, Any] = {
            "effects": list(model.effects),
            "values": res.values,
            "errors": res.errors,
            "free_names": res.free_names,
            "nll": res.nll,
            "deviance_per_dof": res.deviance_per_dof,
            "p_value": res.p_value,
            "pose_error": res.pose_error,
            "converged": res.converged,
        }
