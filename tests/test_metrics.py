"""Paper 000 run metrics (eq. 13, 15, 16) against closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.metrics import gaussian_entropy, kl_divergence, kl_gaussian, total_variance, weighted_mean_cov


def test_weighted_mean_cov_equals_unweighted_duplicates():
    p = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 2.0]])
    w = np.array([1.0, 2.0, 1.0])
    dup = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [1.0, 2.0]])
    mu, cov = weighted_mean_cov(p, w)
    mu2, cov2 = weighted_mean_cov(dup)
    np.testing.assert_allclose(mu, mu2)
    np.testing.assert_allclose(cov, cov2)


def test_total_variance_eq13():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(200_000, 2)) * [2.0, 1.0]
    assert total_variance(p) == pytest.approx(np.hypot(4.0, 1.0), rel=0.02)


def test_entropy_eq15_matches_closed_form():
    rng = np.random.default_rng(1)
    cov = np.array([[2.0, 0.3], [0.3, 0.5]])
    p = rng.multivariate_normal([1, 2], cov, size=200_000)
    expected = 1 + np.log(2 * np.pi) + 0.5 * np.log(np.linalg.det(cov))
    assert gaussian_entropy(p) == pytest.approx(expected, abs=0.01)
    assert gaussian_entropy(np.zeros((10, 2))) == -np.inf


def test_kl_eq16_properties():
    mu = np.array([0.0, 0.0])
    c = np.diag([1.0, 2.0])
    assert kl_gaussian(mu, c, mu, c) == pytest.approx(0.0, abs=1e-12)
    # 1-D textbook value: KL(N(0,1)||N(1,4)) = ln 2 + (1 + 1)/8 - 1/2
    assert kl_gaussian([0.0], [[1.0]], [1.0], [[4.0]]) == pytest.approx(np.log(2) + 2 / 8 - 0.5)
    assert kl_gaussian(mu, c, [1.0, 0.0], c) == pytest.approx(0.5)
    assert kl_gaussian(mu, np.zeros((2, 2)), mu, c) == np.inf
    rng = np.random.default_rng(2)
    a = rng.normal(size=(50_000, 2))
    b = rng.normal(size=(50_000, 2)) + [1.0, 0.0]
    assert kl_divergence(a, b) == pytest.approx(0.5, abs=0.03)


def test_rejects_bad_weights():
    with pytest.raises(ValueError):
        weighted_mean_cov(np.zeros((3, 2)), np.array([1.0, -1.0, 1.0]))
    with pytest.raises(ValueError):
        weighted_mean_cov(np.zeros((3, 2)), np.zeros(3))


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(-50, 50), st.floats(-50, 50), st.floats(0.1, 10))
def test_metrics_properties(seed, dx, dy, scale):
    """KL >= 0 with equality for the same cloud; entropy and total variance are translation invariant;
    scaling the cloud by s multiplies the total variance by s^2 and adds 2 ln s to the entropy."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(300, 2)) @ rng.normal(size=(2, 2)) + rng.normal(size=2)
    w = rng.random(300) + 0.01
    q = rng.normal(size=(300, 2))
    assert kl_divergence(p, q, w) >= -1e-9
    assert kl_divergence(p, p, w, w) == pytest.approx(0.0, abs=1e-9)
    moved = p + [dx, dy]
    assert total_variance(moved, w) == pytest.approx(total_variance(p, w), rel=1e-6)
    assert gaussian_entropy(moved, w) == pytest.approx(gaussian_entropy(p, w), abs=1e-6)
    assert total_variance(scale * p, w) == pytest.approx(scale**2 * total_variance(p, w), rel=1e-6)
    assert gaussian_entropy(scale * p, w) == pytest.approx(gaussian_entropy(p, w) + 2 * np.log(scale), abs=1e-6)
