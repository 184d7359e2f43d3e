"""The position uncertainty a fit's local curvature misses: other modes of the likelihood over the search area.

A fit's covariance is the curvature at the optimum it found. With few dwells the Poisson likelihood has several
modes (a mirror position across the dwells' line, a far strong source against a near weak one), and a fit that
sits in one of them reports its narrow local ellipse: ``radseek replay`` on lattice-clean gave, after 4 dwells,
1-sigma 0.149 m at an error of 2.5 m, the fit 10 nats worse than the cells around the truth.

:func:`mode_covariance` integrates the profile likelihood (source strength and background at their optimum per
cell, as the start grid ``estimator.mle.grid_starts``) over a grid on the scenario's bounds under a flat prior:
the estimate's own mode is the Gaussian of its (misfit-inflated) covariance, every cell farther than three of its
1-sigmas a point mass of the cell's area. The second moment of that mixture about the estimate is the mean squared
error the data allow; its x-y block covers the local one. The grid model is the baseline one (plus the mapped
walls at the fitted ``mu`` of a walled estimate), without pose offsets; the estimate's likelihood is taken with the
same model, so the comparison between modes is like for like.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import logsumexp

from estimator.mle import grid_cell_fit, pooled
from radseek.count_model import expected_rate
from radseek.dataset import Frames, Scenario
from radseek.geometry import path_lengths

__all__ = ["GRID_CELLS", "Modes", "misfit_factor", "mode_covariance"]

#: cells per side of the grid over the scenario's bounds (lattice scenes 10 m: 0.4 m cells, as the start grid)
GRID_CELLS = 25
#: m: a degenerate local ellipse still counts as a mode this wide (``estimator.inflight.MIN_SIGMA_M``)
_MIN_SIGMA_M = 5e-3
#: nats: cells farther than this above the estimate on the screen (frames pooled 10 at a time) carry no mass
SCREEN_NATS = 200.0
#: frames pooled this many at a time where the mass is computed (a transit chunk spans 0.3 m)
FINE_POOL = 3
#: coarse cells within this many nats of the best far cell are integrated again on a finer sub-grid ...
REFINE_DELTA = 20.0
#: ... of REFINE x REFINE points each, at most REFINE_MAX of them
REFINE = 6
REFINE_MAX = 12


@dataclass
class Modes:
    """The mixture's second moment about the estimate (``covariance``, 2 x 2, m^2), the share of the
    probability away from the estimate's own mode (``far_share``), and the best cell away from it
    (``best_x``, ``best_y``, m) with its -log L minus the estimate's (``best_delta``, misfit-scaled; negative: a
    better optimum elsewhere)."""

    covariance: np.ndarray
    far_share: float
    best_x: float
    best_y: float
    best_delta: float


def misfit_factor(deviance_per_dof: Any) -> float:
    """The quasi-likelihood dispersion: deviance per degree of freedom when above 1 (counts scatter more than
    Poisson: the model misses something), else 1. Covariances scale by it and log-likelihood differences shrink
    by it."""
    try:
        phi = float(deviance_per_dof)
    except (TypeError, ValueError):
        return 1.0
    return phi if math.isfinite(phi) and phi > 1.0 else 1.0


def _nll(scenario: Scenario, frames: Frames, cells: np.ndarray, mu_wall: float) -> np.ndarray:
    """-log L (up to a constant) of the baseline model with a source at each row of ``cells`` (x, y, z), its
    strength and the background at their optimum (``estimator.mle.grid_cell_fit``), the mapped walls at ``mu_wall``."""
    from estimator.model import MeasurementModel

    n = MeasurementModel(scenario).observed_counts(frames).astype(float)
    d2 = ((frames.positions[None, :, :] - cells[:, None, :]) ** 2).sum(-1)
    u = frames.duration * expected_rate(d2, 1.0)
    if mu_wall > 0 and scenario.walls:
        u = u * np.exp(-mu_wall * path_lengths(frames.positions[None, :, :], cells[:, None, :], scenario.walls))
    return grid_cell_fit(u, n, frames.duration, max(scenario.background_cps, 1.0))[2]


def mode_covariance(scenario: Scenario, frames: Frames, estimate: dict[str, Any], local: Any, phi: float = 1.0,
                    n_grid: int = GRID_CELLS) -> Modes:
    """:class:`Modes` of the likelihood of ``frames`` about ``estimate`` (``x``, ``y``, ``z``; ``params`` may
    carry ``wall_attenuation.mu_per_m``) whose local x-y covariance is ``local`` (m^2, already inflated by
    ``phi``, :func:`misfit_factor`), on an ``n_grid`` x ``n_grid`` grid over the scenario's bounds.

    The grid is screened on frames pooled 10 at a time (a transit chunk then spans 1 m, and at 1.5 m from a
    strong source its mean pose misstates the rate by a few per cent: hundreds of nats over a close pass), and
    only the cells within :data:`SCREEN_NATS` of the estimate there are evaluated on frames pooled
    :data:`FINE_POOL` at a time; those within :data:`REFINE_DELTA` of the best are integrated again on a
    :data:`REFINE` x :data:`REFINE` sub-grid: a mode narrower than a cell (lattice-clean after 4 dwells, 0.1 m)
    falls between the coarse cells."""
    local = np.asarray(local, dtype=float)[:2, :2]
    ex, ey, ez = (float(estimate[k]) for k in ("x", "y", "z"))
    mu_wall = float(estimate.get("params", {}).get("wall_attenuation.mu_per_m", 0.0))
    w, _ = np.linalg.eigh(0.5 * (local + local.T))
    sigma = math.sqrt(max(float(w[-1]), _MIN_SIGMA_M**2))
    none = Modes(local, 0.0, math.nan, math.nan, math.nan)
    gx = np.linspace(scenario.bounds_min[0], scenario.bounds_max[0], n_grid)
    gy = np.linspace(scenario.bounds_min[1], scenario.bounds_max[1], n_grid)
    hx, hy = float(gx[1] - gx[0]), float(gy[1] - gy[0])
    xx, yy = (a.ravel() for a in np.meshgrid(gx, gy))
    keep = np.hypot(xx - ex, yy - ey) > max(3.0 * sigma, 1.5 * math.hypot(hx, hy))
    xx, yy = xx[keep], yy[keep]
    if not len(xx):
        return none

    def delta(pts_x: np.ndarray, pts_y: np.ndarray, fr: Frames) -> np.ndarray:
        """Misfit-scaled -log L at the points minus the estimate's (+inf where the fit is not finite)."""
        cells = np.stack([np.r_[ex, pts_x], np.r_[ey, pts_y], np.full(len(pts_x) + 1, ez)], 1)
        nll = _nll(scenario, fr, cells, mu_wall)
        return np.where(np.isfinite(nll[1:]), nll[1:] - nll[0], np.inf) / max(phi, 1.0)

    keep = delta(xx, yy, pooled(frames)) < SCREEN_NATS
    xx, yy = xx[keep], yy[keep]
    if not len(xx):
        return none
    fine_frames = pooled(frames, FINE_POOL)
    dl = delta(xx, yy, fine_frames)
    log_m = math.log(hx * hy) - dl  # each cell's mass: its area times its likelihood relative to the estimate's
    refine = np.flatnonzero(dl < dl.min() + REFINE_DELTA)[:REFINE_MAX]
    if len(refine):
        s = (np.arange(REFINE) + 0.5) / REFINE - 0.5
        sx, sy = (a.ravel() for a in np.meshgrid(s * hx, s * hy))
        fx, fy = (xx[refine, None] + sx).ravel(), (yy[refine, None] + sy).ravel()
        out = np.hypot(fx - ex, fy - ey) > 3.0 * sigma
        fx, fy = fx[out], fy[out]
        fine = delta(fx, fy, fine_frames)
        log_m[refine] = -np.inf  # replaced by their sub-cells
        log_m = np.r_[log_m, math.log(hx * hy / REFINE**2) - fine]
        xx, yy, dl = np.r_[xx, fx], np.r_[yy, fy], np.r_[dl, fine]
    d = np.stack([xx - ex, yy - ey], 1)
    # the estimate's own mode: its likelihood times the Gaussian's 2 pi sqrt(det)
    log_m0 = math.log(2.0 * math.pi * max(math.sqrt(max(float(w[0]), 0.0) * max(float(w[-1]), 0.0)),
                                          _MIN_SIGMA_M**2))
    log_all = np.r_[log_m0, log_m]
    p = np.exp(log_all - logsumexp(log_all))
    cov = p[0] * local + np.einsum("i,ia,ib->ab", p[1:], d, d)
    best = int(np.argmin(dl))
    return Modes(cov, float(1.0 - p[0]), float(xx[best]), float(yy[best]), float(dl[best]))
