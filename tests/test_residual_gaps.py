"""Binned residual trends break their plotted line where bins are empty (issue 35: lines joined across gaps)."""

from __future__ import annotations

import numpy as np

from estimator.diagnose.residuals import broken_at_gaps, trend


def test_a_gap_in_a_log_binned_feature_breaks_the_line():
    """Rates at 1-2 and 50-100 cps, binned on equal steps of the log: the bins in between are empty. The trend
    keeps the filled bins only, records where the gap is, and the plotted series has NaN there."""
    rng = np.random.default_rng(0)
    rate = np.r_[rng.uniform(1, 2, 300), rng.uniform(50, 100, 300)]
    mu = rate * 10.0
    n = rng.poisson(mu)
    t = trend("count rate", rate, n, mu, n_bins=8, log=True)
    assert t is not None and len(t.gaps_after) == 1
    i = t.gaps_after[0]
    assert t.centres[i] < 2.0 < 50.0 < t.centres[i + 1]  # the gap lies between these two filled bins
    x, y = broken_at_gaps(t, t.centres, t.rel)
    assert len(x) == len(t.centres) + 1 and np.isnan(x[i + 1]) and np.isnan(y[i + 1])
    assert np.isfinite(np.delete(x, i + 1)).all()


def test_no_gap_no_break():
    rng = np.random.default_rng(1)
    f = rng.uniform(0, 10, 500)
    t = trend("time", f, rng.poisson(20.0, 500), np.full(500, 20.0))
    assert t.gaps_after == ()
    (x,) = broken_at_gaps(t, t.centres)
    np.testing.assert_array_equal(x, t.centres)
