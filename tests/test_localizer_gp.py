"""Paper 001 GP reconstruction + peak analysis: GP algebra, single peak, two peaks."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.analytic_flights import dwell_frames, lattice_flight, scenario_for
from estimator.localizers import make_localizer
from estimator.localizers.gaussian_process import GaussianProcess, find_peaks


def test_gp_interpolates_noise_free_points():
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 5, (15, 2))
    y = np.sin(x[:, 0]) + np.cos(x[:, 1])
    gp = GaussianProcess(x, y, np.full(15, 1e-8), n_restarts=2)
    m, v = gp.predict(x)
    np.testing.assert_allclose(m, y, atol=1e-2)
    assert np.all(v < 1e-2)
    mfar, vfar = gp.predict(np.array([[50.0, 50.0]]))
    assert mfar[0] == pytest.approx(gp.mean, abs=1e-6) and vfar[0] == pytest.approx(gp.sigma_f**2, rel=1e-6)


def test_find_peaks_orders_by_height():
    xx, yy = np.meshgrid(np.arange(50), np.arange(40), indexing="ij")
    f = 3 * np.exp(-((xx - 10) ** 2 + (yy - 10) ** 2) / 20) + 2 * np.exp(-((xx - 35) ** 2 + (yy - 30) ** 2) / 20)
    assert find_peaks(f)[:2] == [(10, 10), (35, 30)]


@pytest.mark.slow
def test_single_source_lattice():
    errs = []
    for seed in range(3):
        ds = lattice_flight(seed)
        loc = make_localizer("gp", grid_step=0.05, n_restarts=2, n_posterior_samples=50).fit(ds)
        tr = ds.truth.sources[0]
        errs.append(np.hypot(loc.position_[0] - tr.x, loc.position_[1] - tr.y))
    assert np.median(errs) < 0.5
    assert loc.covariance_.shape == (4, 4) and np.all(loc.position_std()[:2] > 0)


def test_two_sources_two_peaks():
    srcs = [(2.5, 2.5, 0.0, 2000.0), (7.5, 5.5, 0.0, 1500.0)]
    pts = np.array([[x, y, 1.4] for x in np.arange(1.0, 9.6, 1.2) for y in np.arange(1.0, 7.6, 1.2)])
    frames = dwell_frames(pts, srcs, 30.0, dwell_s=5.0, rng=np.random.default_rng(1))
    loc = make_localizer("gp", n_sources="auto", n_restarts=2, n_posterior_samples=0).fit(frames, scenario_for())
    assert len(loc.sources_) == 2
    got = sorted((s["x"], s["y"]) for s in loc.sources_)
    assert np.hypot(got[0][0] - 2.5, got[0][1] - 2.5) < 0.4
    assert np.hypot(got[1][0] - 7.5, got[1][1] - 5.5) < 0.4
    two = make_localizer("gp", n_sources=2, n_restarts=2, n_posterior_samples=0).fit(frames, scenario_for())
    assert len(two.sources_) == 2
