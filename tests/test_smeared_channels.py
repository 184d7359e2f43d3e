"""The smeared channel contents of the spectral model (spectra.model._smeared_channels), against analytic cases."""

import numpy as np
from scipy.special import ndtr

from spectra.model import SMEAR_REACH_SD, _smeared_channels


def test_a_far_tail_channel_has_its_analytic_content_to_full_relative_precision():
    # one Gaussian (m 0, sd 1, weight 1): the channel [b, b + 0.5] holds Phi(-b) - Phi(-b - 0.5) exactly; 7-9.5 sd
    # out that is 1e-12..1e-21 of the weight, where a difference of two cumulative sums near 1 is rounding noise
    b = np.arange(-3.0, 9.51, 0.5)
    got = _smeared_channels(b, np.array([0.0]), np.array([1.0]), np.array([1.0]))
    want = ndtr(-b[:-1]) - ndtr(-b[1:])
    tail = b[:-1] >= 7.0
    np.testing.assert_allclose(got[tail], want[tail], rtol=1e-12)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-16)
    dense = np.diff(ndtr(b))  # the cancelling form: its far tail is wrong by orders of magnitude
    assert np.max(np.abs(dense[tail] / want[tail] - 1)) > 1e-3


def test_many_points_agree_with_the_dense_sum_and_nothing_is_lost_beyond_reach():
    rng = np.random.default_rng(3)
    m = rng.uniform(0, 1000, 300)
    s = rng.uniform(0.5, 40, 300)
    w = rng.exponential(1.0, 300)
    b = np.linspace(-200, 1300, 1001)
    got = _smeared_channels(b, m, s, w)
    dense = np.diff(ndtr((b[:, None] - m[None, :]) / s[None, :]) @ w)
    np.testing.assert_allclose(got, dense, rtol=0, atol=1e-12 * w.sum())
    assert abs(got.sum() - w.sum()) < 1e-12 * w.sum()  # every point lies well inside the channels
    # a point centred on a boundary and a point outside every channel
    edge = _smeared_channels(np.array([0.0, 1.0, 2.0]), np.array([1.0, 50.0]), np.array([0.1, 1.0]),
                             np.array([1.0, 1.0]))
    np.testing.assert_allclose(edge, [0.5, 0.5], rtol=1e-15)
    assert SMEAR_REACH_SD >= 10  # Phi(-10) = 7.6e-24: below the likelihood's 1e-12 count floor up to 1e11 counts


def test_falling_boundaries_take_the_dense_sum():
    b = np.array([3.0, 2.0, 1.0])
    got = _smeared_channels(b, np.array([2.0]), np.array([0.5]), np.array([1.0]))
    np.testing.assert_allclose(got, np.diff(ndtr((b - 2.0) / 0.5)), rtol=1e-15)
