"""Odometry drift as physics: the pose error is one random walk in distance flown (issue 13).

The flights here come from a forward model written for this test (not the emulator, not the estimator's
model): a drone flies a lattice of dwell points at constant speed, its odometry error is a Brownian
motion in distance flown, the detector sees a point source by the inverse-square law plus background.
"""

from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from estimator.localizers.mle import pose_aware_crlb
from estimator.mle import INDEPENDENT, RANDOM_WALK, PoseGroups, fit, pose_error_model
from estimator.model import MeasurementModel
from radseek.dataset import Frames, Scenario

SCEN = Scenario(channel_edges_keV=np.linspace(40, 1640, 33), background_cps=30.0, source_z=0.0,
                bounds_min=np.array([0.0, 0.0, 0.0]), bounds_max=np.array([10.0, 10.0, 3.0]))
SOURCE = np.array([4.3, 5.6, 0.0])
CPS_1M, BKG = 1600.0, 30.0
DENSITY = 0.06**2  # m^2 of drift variance per metre flown (twice the mock vehicle's sd: drift dominates)


def drifting_flight(seed: int, density: float = DENSITY, dwell_s: float = 6.0) -> Frames:
    """A lattice flown from a corner at 1 m/s; frames pooled to 1 s while dwelling, 0.2 s in transit."""
    rng = np.random.default_rng(seed)
    pts = [(1.0, 1.0)] + [(4.5 + 1.5 * i, 5.5 + 1.5 * j) for i in (-1, 0, 1) for j in (-1, 0, 1) if i or j]
    est, drift, var, t, s = np.array([0.5, 0.5, 1.5]), np.zeros(3), 1e-4, 0.0, 0.0
    rows = []

    def frame(dt, dwell):
        nonlocal t
        true = est - drift
        mu = (CPS_1M / max(np.sum((true - SOURCE) ** 2), 0.05**2) + BKG) * dt
        t += dt
        rows.append([t, dt, *est, 0.0, var, var, var * 0.1, dwell, rng.poisson(mu)] + [0] * 31)

    for k, p in enumerate(pts):
        target = np.array([p[0], p[1], 1.5])
        while (d := np.linalg.norm(target - est)) > 1e-9:
            step = min(d, 0.2)
            est = est + (target - est) / d * step
            drift = drift + rng.normal(0, np.sqrt(density * step), 3) * [1, 1, np.sqrt(0.1)]
            var, s = var + density * step, s + step
            frame(0.2, -1)
        for _ in range(int(dwell_s)):
            frame(1.0, k)
    return Frames.from_rows(np.array(rows, dtype=float))


def brownian_cov(var: np.ndarray) -> np.ndarray:
    """Cov(e_j, e_k) = var_min(j, k) for a random walk sampled where its variance is var (ascending)."""
    return np.minimum.outer(var, var)


def test_the_error_model_is_read_from_the_variance_columns():
    f = drifting_flight(0)
    assert pose_error_model(f) == RANDOM_WALK
    const = Frames.from_rows(np.column_stack([f.t, f.duration, f.x, f.y, f.z, f.yaw, np.full(len(f), 1.7e-3),
                                              np.full(len(f), 1.7e-3), np.full(len(f), 3e-4), f.dwell, f.counts]))
    assert pose_error_model(const) == INDEPENDENT
    assert pose_error_model(const, "random_walk") == RANDOM_WALK  # scenario.json pose_error wins
    with pytest.raises(ValueError, match="pose_error"):
        pose_error_model(f, "brownian")


def test_random_walk_prior_is_the_brownian_covariance():
    """The banded precision and solve equal the dense inverse of Cov(e_j, e_k) = var(min(j, k))."""
    g = PoseGroups.from_frames(drifting_flight(1))
    assert g.kind == RANDOM_WALK and g.n_groups > 20
    rng = np.random.default_rng(0)
    delta = rng.normal(size=(g.n_groups, 3))
    fisher = rng.normal(size=(g.n_groups, 3, 3))
    fisher = fisher @ fisher.transpose(0, 2, 1)
    rhs = rng.normal(size=(g.n_groups, 3))
    dense = np.zeros((3 * g.n_groups,) * 2)
    for j in range(3):
        dense[j::3, j::3] = np.linalg.inv(brownian_cov(g.variance[:, j]))
    np.testing.assert_allclose(g.prior_times(delta).ravel(), dense @ delta.ravel(), rtol=1e-8, atol=1e-6)
    for k in range(g.n_groups):
        dense[3 * k:3 * k + 3, 3 * k:3 * k + 3] += fisher[k]
    np.testing.assert_allclose(g.solve(fisher, rhs).ravel(), np.linalg.solve(dense, rhs.ravel()), rtol=1e-6)


def _mahalanobis(r):
    i = [r.free_names.index("x"), r.free_names.index("y")]
    d = np.array([r.values["x"] - SOURCE[0], r.values["y"] - SOURCE[1]])
    return float(d @ np.linalg.solve(np.asarray(r.covariance)[np.ix_(i, i)], d))


@pytest.mark.slow
def test_reported_covariance_holds_the_drift():
    """Under drift, the squared Mahalanobis distance of the error has mean 2 (chi2 with 2 dof) if the
    covariance is honest. Over 24 flights its mean has sd sqrt(4/24) = 0.41: the random-walk model must stay
    below 2 + 3 x 0.41; the per-dwell independent model, which treats a common shift of all poses as averaged
    away, must not (else this test could not fail)."""
    m = MeasurementModel(SCEN)
    rw, ind = [], []
    for seed in range(24):
        f = drifting_flight(100 + seed)
        init = {"x": 4.5, "y": 5.5, "cps_at_1m": CPS_1M, "background_cps": BKG}
        rw.append(_mahalanobis(fit(m, f, n_starts=1, init=init)))
        independent = MeasurementModel(replace(SCEN, extra={"pose_error": INDEPENDENT}))
        ind.append(_mahalanobis(fit(independent, f, n_starts=1, init=init)))
    bound = 2 + 3 * np.sqrt(4 / 24)
    assert np.mean(rw) < bound, np.round(rw, 1)
    assert np.mean(ind) > bound, np.round(ind, 1)
    # and the 95 % ellipse: P(fewer than 20 of 24 inside | coverage 0.95) = binom.cdf(19, 24, 0.95) = 0.7 %
    assert sum(x < stats.chi2.ppf(0.95, 2) for x in rw) >= 20


def test_drift_aware_bound_exceeds_the_exact_pose_bound():
    """With the drift as a nuisance, the bound on the source position can only grow, and by about the
    drift accumulated before the informative dwells (~ sqrt(DENSITY x 10 m) ~ 0.2 m here)."""
    from estimator.mle import crlb

    f = drifting_flight(7)
    m = MeasurementModel(SCEN)
    theta = {"x": SOURCE[0], "y": SOURCE[1], "cps_at_1m": CPS_1M, "background_cps": BKG}
    exact = np.sqrt(np.trace(crlb(m, theta, f)[:2, :2]))
    drift = np.sqrt(np.trace(pose_aware_crlb(m, theta, f)[:2, :2]))
    assert exact < 0.05 < 0.1 < drift < 0.5, (exact, drift)
