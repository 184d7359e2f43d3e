"""Poisson maximum likelihood as a localizer: wraps :func:`estimator.mle.fit` and :func:`estimator.mle.crlb`.

The model is :class:`estimator.model.MeasurementModel` with the chosen ``effects`` (any subset of the
effect vocabulary except ``gain_drift``): per-frame total counts n_i ~ Poisson(mu_i(theta)), maximised
multi-start and bounded (MIGRAD), with the per-dwell pose offsets profiled out when
``pose_uncertainty``. ``covariance_`` is the inverse Hessian of the negative log-likelihood (Fisher
information, HESSE); ``crlb_`` is the Cramér-Rao bound for the flown poses at the estimate: paper 004
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

__all__ = ["MaximumLikelihood", "source_param_names", "pose_aware_crlb"]

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


def pose_aware_crlb(model, theta: dict[str, float], frames: Frames, step_m: float = 1e-3) -> np.ndarray:
    """CRLB of the free parameters when every dwell's pose offset is an unknown with its reported prior.

    The Poisson CRLB (:func:`estimator.mle.crlb`) assumes the recorded poses are exact. With per-dwell offsets
    delta_g ~ N(0, diag(var)) as nuisance parameters (as :func:`estimator.mle.fit` models them), the hybrid
    information is [[J_tt, J_td], [J_dt, J_dd + Sigma^-1]] and the bound on theta is the inverse of its Schur
    complement J_tt - sum_g J_td,g (J_dd,g + Sigma_g^-1)^-1 J_dt,g (one 3 x 3 block per dwell/transit run).
    """
    from estimator.mle import PoseGroups, expected_count_gradient

    full = {**model.defaults(), **theta}
    mu = np.maximum(model.expected_counts(full, frames), 1e-12)
    gt = expected_count_gradient(model, full, frames)  # (N, k)
    gd = np.empty((len(frames), 3))
    for a in range(3):
        shift = np.zeros((len(frames), 3))
        shift[:, a] = step_m
        up = model.expected_counts(full, frames, offsets=shift)
        dn = model.expected_counts(full, frames, offsets=-shift)
        gd[:, a] = (up - dn) / (2 * step_m)
    j = (gt / mu[:, None]).T @ gt
    groups = PoseGroups.from_frames(frames)
    for g in range(groups.n_groups):
        var = groups.variance[g]
        active = var > 1e-12
        if not active.any():
            continue
        m = groups.index == g
        a_ = gd[m][:, active]
        jdd = (a_ / mu[m, None]).T @ a_ + np.diag(1.0 / var[active])
        jtd = (gt[m] / mu[m, None]).T @ a_
        j -= jtd @ np.linalg.solve(jdd, jtd.T)
    return np.linalg.pinv(j)


class MaximumLikelihood(Localizer):
    """Poisson MLE with Fisher covariance and CRLB (see module docstring)."""

    name = "mle"

    def __init__(self, effects: Sequence[str] = (), n_starts: int = 8, seed: int = 0, pose_uncertainty: bool = True,
                 fixed: Mapping[str, float] | None = None, init: Mapping[str, float] | None = None,
                 compute_crlb: bool = True, energy_window_keV: Sequence[float] | None = None):
        self.effects = effects
        self.n_starts = n_starts
        self.seed = seed
        self.pose_uncertainty = pose_uncertainty
        self.fixed = fixed
        self.init = init
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
                  init=dict(self.init) if self.init else None)
        per_source = source_param_names(model.effects)
        self.result_ = res
        self.sources_ = [source_dict(*(res.values[n] for n in names)) for names in per_source]
        self.covariance_ = _embed(np.asarray(res.covariance, dtype=float), res.free_names, per_source)
        self.background_ = float(res.values["background_cps"])
        self.crlb_ = None
        self.crlb_pose_ = None
        if self.compute_crlb:
            c = crlb(model, res.values, frames)
            self.crlb_ = _embed(c, model.free_names, per_source)
            self.crlb_full_ = c
            if self.pose_uncertainty and np.any(frames.pose_variances > 0):
                self.crlb_pose_ = _embed(pose_aware_crlb(model, res.values, frames), model.free_names, per_source)
        self.info_: dict[str, Any] = {
            "effects": list(model.effects),
            "values": res.values,
            "errors": res.errors,
            "free_names": res.free_names,
            "nll": res.nll,
            "deviance_per_dof": res.deviance_per_dof,
            "p_value": res.p_value,
            "converged": res.converged,
        }
