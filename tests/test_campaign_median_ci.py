"""The campaign's confidence interval of the median: exact order statistics with the coverage they have."""

import math

import numpy as np
import pytest

from launch.campaign import _ci_text, median_ci


def test_too_few_flights_give_no_interval_and_say_what_min_max_covers():
    med, lo, hi, cover = median_ci(np.array([3.0, 1.0, 2.0, 5.0, 4.0]))
    assert med == 3.0
    assert math.isnan(lo) and math.isnan(hi)
    assert cover == pytest.approx(1 - 2 / 2**5)  # [min, max] of 5: 93.75 %
    assert "too few" in _ci_text(lo, hi, cover)
    assert median_ci(np.array([1.0, 2.0, 3.0]))[3] == pytest.approx(0.75)  # the n = 3 case


@pytest.mark.parametrize(("n", "r", "cover"), [(6, 1, 1 - 2 / 64), (20, 6, 0.958610), (100, 40, 0.964800)])
def test_order_statistics_and_coverage_match_the_binomial_tables(n, r, cover):
    x = np.arange(1.0, n + 1)  # x_(k) = k
    _, lo, hi, c = median_ci(np.random.default_rng(0).permutation(x))
    assert (lo, hi) == (r, n + 1 - r)
    assert c == pytest.approx(cover, abs=5e-6)
    assert c >= 0.95


def test_stated_coverage_holds_on_skewed_samples():
    """4,000 samples of 11 exponential errors: the interval holds the true median at its stated coverage
    (within 3 binomial sd)."""
    rng = np.random.default_rng(7)
    true_median = math.log(2.0)
    hits, stated = 0, []
    for _ in range(4000):
        _, lo, hi, c = median_ci(rng.exponential(1.0, 11))
        hits += lo <= true_median <= hi
        stated.append(c)
    c = float(np.mean(stated))
    assert c == pytest.approx(0.9883, abs=1e-3)  # n = 11: (x_(2), x_(10))
    assert abs(hits / 4000 - c) <= 3 * math.sqrt(c * (1 - c) / 4000)
