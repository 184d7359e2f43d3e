"""Poisson maximum likelihood as a localizer: wraps :func:`estimator.mle.fit` and :func:`estimator.mle.crlb`.

The model is :class:`estimator.model.MeasurementModel` with the chosen ``effects`` (any subset of the
effect vocabulary except ``gain_drift``): per-frame total counts n_i ~ Poisson(mu_i(theta)), maximised
multi-start and bounded (MIGRAD), with the per-dwell pose offsets profiled out when
``pose_uncertainty``. ``covariance_`` is the inverse Hessian of the negative log-likelihood (Fisher
information, HESSE); ``crlb_`` is the Cramér-Rao bound for the flown poses at the estimate: paper 004
eq. 5.3-5.7 generalised to the Poisson likelihood and the model's free parameters (J = sum_i grad mu_i
grad mu_i^T / mu_i), inverted over all free parameters and then restricted to (x, y, z, cps_at_1m) per
source (so nuisance parameters such as the background are accounted for, not ignored).

A ``second_source`` effect gives a second entry in ``sources_``. ``fixed`` pins parameters at given
values (e.g. ``{"dead_time.tau_s": 1.2e-5}`` for a calibrated detector).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from estimator.localizers.base import Localizer, source_dict
from radseek.dataset import Frames, Scenario

__all__ = ["MaximumLikelihood", "source_param_names"]

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


class MaximumLikelihood(Localizer):
    """Poisson MLE with Fisher covariance and CRLB (see module docstring)."""

    name = "mle"

    def __init__(self, effects: Sequence[str] = (), n_starts: int = 8, seed: int = 0, pose_uncertainty: bool = True,
                 fixed: Mapping[str, float] | None = None, init: Mapping[str, float] | None = None,
                 compute_crlb: bool = True):
        self.effects = effects
        self.n_starts = n_starts
        self.seed = seed
        self.pose_uncertainty = pose_uncertainty
        self.fixed = fixed
        self.init = init
        self.compute_crlb = compute_crlb

    def model_for(self, scenario: Scenario):
        from estimator.model import MeasurementModel

        model = MeasurementModel(scenario, effects=tuple(self.effects))
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
            "converged": res.converged,
        }
