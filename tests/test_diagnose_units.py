"""Pure pieces of radseek diagnose: residuals, features, null distributions, explanations, JSON cleaning."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from estimator.diagnose.backend import VOCABULARY
from estimator.diagnose.explain import PHYSICS, feature_of, physics
from estimator.diagnose.features import compute_features
from estimator.diagnose.residuals import (
    deviance_moments,
    deviance_residuals,
    goodness_of_fit,
    pearson,
    segments,
    trend,
    unit_deviance,
)
from estimator.diagnose.selection import null_log10_p, second_source_looks
from radseek.dataset import Frames, Scenario, Wall


def _frames(n: int = 50, dwell: np.ndarray | None = None, yaw: float = 0.0) -> Frames:
    t = np.arange(1, n + 1) * 0.1
    z = np.zeros(n)
    return Frames(t=t, duration=np.full(n, 0.1), x=np.linspace(0, 4, n), y=np.zeros(n), z=z + 1.0,
                  yaw=np.full(n, yaw), var_x=z, var_y=z, var_z=z,
                  dwell=np.full(n, -1) if dwell is None else dwell, counts=np.ones((n, 32), dtype=int))


def _scenario(walls=()) -> Scenario:
    return Scenario(np.linspace(40, 3000, 33), 30.0, 0.0, np.zeros(3), np.array([10.0, 8.0, 0.5]), tuple(walls))


@pytest.mark.parametrize("mu", [0.3, 3.0, 30.0])
def test_deviance_moments_match_monte_carlo(mu):
    rng = np.random.default_rng(0)
    n = rng.poisson(mu, 400_000)
    d = unit_deviance(n, np.full(n.shape, mu))
    m, v = deviance_moments(np.array([mu]))
    assert abs(d.mean() - m[0]) < 0.01
    assert abs(d.var() - v[0]) < 0.05 * v[0]


def test_goodness_of_fit_is_calibrated_for_low_counts():
    rng = np.random.default_rng(1)
    mu = rng.uniform(1, 6, 5000)
    ps = [goodness_of_fit(rng.poisson(mu), mu, 0).p_value for _ in range(200)]
    # p-values uniform: about 1 % below 0.01, and the median near 0.5
    assert np.mean(np.array(ps) < 0.05) < 0.12
    assert 0.35 < np.median(ps) < 0.65


def test_residuals_signs_and_zero_counts():
    n = np.array([0, 5, 10])
    mu = np.array([1.0, 5.0, 5.0])
    assert np.allclose(pearson(n, mu), [-1, 0, 5 / math.sqrt(5)])
    dr = deviance_residuals(n, mu)
    assert dr[0] < 0 and dr[1] == 0 and dr[2] > 0
    assert np.isclose(dr[0] ** 2, 2.0)


def test_trend_finds_a_falling_residual_and_ignores_noise():
    rng = np.random.default_rng(2)
    rate = np.exp(rng.uniform(np.log(30), np.log(3000), 4000))
    mu = rate * 0.1
    lost = np.exp(-rate * 1e-4)  # dead-time-like loss
    tr = trend("count rate", rate, rng.poisson(mu * lost), mu, log=True)
    assert tr is not None and tr.p_value < 1e-6 and tr.slope_z < -3
    ok = trend("count rate", rate, rng.poisson(mu), mu, log=True)
    assert ok is not None and ok.p_value > 1e-3


def test_segments_split_dwells_and_transit():
    dwell = np.array([-1] * 25 + [0] * 10 + [-1] * 5 + [1] * 10)
    lab = segments(_frames(50, dwell), transit_s=1.0)
    assert len(np.unique(lab[25:35])) == 1 and len(np.unique(lab[:25])) == 3
    assert lab[40] != lab[34] and np.all(np.diff(lab) >= 0)


def test_features_bearing_back_angle_and_walls():
    f = _frames(3)
    wall = Wall((2.0, -5.0), (2.0, 5.0), 0.2, 3.0)
    feats = compute_features(f.select(np.array([True, False, False])), _scenario([wall]), np.array([4.0, 0, 0]),
                             np.array([10.0]))
    assert abs(feats.bearing_deg[0]) < 1e-6  # detector axis +x, source at +x
    assert feats.back_angle_deg[0] > 90
    assert 0.19 < feats.walls_m[0, 0] < 0.25  # oblique 3-D path through 0.2 m
    assert np.isclose(feats.rate_cps[0], 100.0)
    behind = compute_features(_frames(3, yaw=np.pi).select(np.array([True, False, False])), _scenario(),
                              np.array([4.0, 0, 0]), np.array([1.0]))
    assert abs(abs(behind.bearing_deg[0]) - 180) < 1e-6 and behind.back_angle_deg[0] < 30


def test_boundary_null_is_half_chi2():
    lp, name = null_log10_p("dead_time", 6.63, 1, _scenario(), _frames())
    assert np.isclose(10**lp, 0.5 * stats.chi2.sf(6.63, 1)) and "boundary" in name
    assert null_log10_p("air_attenuation", 0.0, 1, _scenario(), _frames())[0] == 0.0
    lp2, _ = null_log10_p("background_gradient", 9.21, 2, _scenario(), _frames())
    assert np.isclose(10**lp2, 0.01, rtol=1e-3)


def test_davies_effects_are_stricter_than_their_pointwise_null():
    f = _frames()
    p_point = 0.5 * stats.chi2.sf(20.0, 1)
    lp, name = null_log10_p("second_source", 20.0, 3, _scenario(), f)
    looks = second_source_looks(_scenario(), f)
    assert looks == 80  # 10 m x 8 m at 1 m height
    assert np.isclose(10**lp, looks * p_point) and "Davies" in name
    lpa, _ = null_log10_p("anisotropy", 20.0, 2, _scenario(), f)
    assert 10**lpa > p_point


def test_every_effect_has_physics_and_a_feature():
    assert set(PHYSICS) == set(VOCABULARY)
    for e in VOCABULARY:
        assert len(physics(e)) > 60 and feature_of(e)


def test_cli_offers_the_whole_vocabulary():
    from radseek_cli.diagnose_cli import VOCABULARY as CLI_VOCABULARY

    assert tuple(CLI_VOCABULARY) == VOCABULARY and "over_dispersion" in VOCABULARY


def test_tail_p_values_stay_finite_for_ranking():
    from estimator.diagnose.selection import chi2_logsf

    assert np.isclose(chi2_logsf(1000.0, 1), stats.chi2.logsf(1000.0, 1))
    assert math.isfinite(chi2_logsf(5291.0, 1)) and chi2_logsf(6000.0, 1) < chi2_logsf(5291.0, 1)
    lp, _ = null_log10_p("second_source", 5291.0, 3, _scenario(), _frames())
    assert math.isfinite(lp) and lp < -1000


def test_transit_runs_split_at_turns_only():
    from estimator.diagnose.backend import split_transit_legs

    # dwell 0 (20 frames), an L-shaped transit (2 x 30 frames at 0.1 m/frame), dwell 1 (20 frames)
    leg1 = np.column_stack([np.arange(30) * 0.1, np.zeros(30)])
    leg2 = np.column_stack([np.full(30, 3.0), np.arange(1, 31) * 0.1])
    xy = np.vstack([np.zeros((20, 2)), leg1, leg2, np.tile([3.0, 3.0], (20, 1))])
    n = len(xy)
    dwell = np.r_[np.zeros(20), -np.ones(60), np.ones(20)].astype(int)
    z = np.zeros(n)
    f = Frames(t=np.arange(1, n + 1) * 0.1, duration=np.full(n, 0.1), x=xy[:, 0], y=xy[:, 1], z=z + 1.5, yaw=z,
               var_x=z + 1e-3, var_y=z + 1e-3, var_z=z, dwell=dwell, counts=np.ones((n, 32), dtype=int))
    out = split_transit_legs(f).dwell
    assert np.array_equal(out[:20], dwell[:20]) and np.array_equal(out[80:], dwell[80:])
    transit = out[20:80]
    assert set(transit) == {-1, -2} and np.count_nonzero(np.diff(transit)) == 1  # one cut, at the corner
    assert 45 <= 20 + int(np.flatnonzero(np.diff(transit))[0]) <= 55
