"""MLE localizer: recovers a known source within its own covariance; CRLB layout; registry contract."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.analytic_flights import dwell_frames, lattice_flight, lattice_points, scenario_for
from estimator.localizers import LOCALIZERS, clone, localizer_class, make_localizer


def test_mle_covers_truth_in_90_percent_of_seeded_runs():
    inside = 0
    n = 20
    for seed in range(n):
        ds = lattice_flight(100 + seed)
        loc = make_localizer("mle", n_starts=1, pose_uncertainty=False, compute_crlb=False).fit(ds)
        tr = ds.truth.sources[0]
        err = loc.position_[:2] - [tr.x, tr.y]
        cov = loc.covariance_[:2, :2]
        if err @ np.linalg.solve(cov, err) < 5.99:  # 95 % region of a 2-D Gaussian
            inside += 1
    assert inside >= 0.9 * n


def test_exact_counts_give_exact_source_and_crlb_matches_covariance():
    src = (4.3, 3.7, 0.0, 1600.0)
    frames = dwell_frames(lattice_points((4.3, 3.7)), [src], 30.0, dwell_s=10.0, exact=True)
    loc = make_localizer("mle", n_starts=2, pose_uncertainty=False).fit(frames, scenario_for())
    s = loc.sources_[0]
    # exact counts: the minimum is the truth; MIGRAD stops within an estimated distance of 0.002 * tol *
    # errordef = 1e-3 in -log L (estimator.mle.SEARCH_TOL = 1), i.e. within sqrt(2e-3) = 0.045 sigma of it
    sd = np.sqrt(np.diag(loc.result_.covariance))
    est = np.array([s["x"], s["y"], s["cps_at_1m"], loc.background_])
    assert loc.result_.free_names == ["x", "y", "cps_at_1m", "background_cps"]
    assert np.all(np.abs(est - [4.3, 3.7, 1600.0, 30.0]) <= 0.1 * sd), (est, sd)
    # at the true parameters the observed information equals the expected (Fisher) information
    np.testing.assert_allclose(np.diag(loc.covariance_)[[0, 1, 3]], np.diag(loc.crlb_)[[0, 1, 3]], rtol=0.05)
    assert loc.covariance_[2, 2] == 0.0  # z is fixed at scenario.source_z
    r = loc.result()
    assert r["method"] == "mle" and len(r["crlb"]) == 4


def test_second_source_effect_gives_two_sources():
    srcs = [(3.0, 3.0, 0.0, 2000.0), (7.5, 5.0, 0.0, 1200.0)]
    pts = np.array([[x, y, 1.4] for x in (2.0, 4.0, 6.0, 8.0) for y in (2.0, 4.5, 6.5)])
    frames = dwell_frames(pts, srcs, 30.0, dwell_s=8.0, rng=np.random.default_rng(5))
    loc = make_localizer("mle", effects=("second_source",), n_starts=4, pose_uncertainty=False,
                         compute_crlb=False).fit(frames, scenario_for())
    assert len(loc.sources_) == 2 and loc.covariance_.shape == (8, 8)
    found = sorted((s["x"], s["y"]) for s in loc.sources_)
    assert np.hypot(found[0][0] - 3.0, found[0][1] - 3.0) < 0.2
    assert np.hypot(found[1][0] - 7.5, found[1][1] - 5.0) < 0.3


def test_registry_and_sklearn_contract():
    assert set(LOCALIZERS) == {"sphere", "pf", "multi-pf", "gp", "mle"}
    for name in LOCALIZERS:
        cls = localizer_class(name)
        loc = cls()
        params = loc.get_params()
        c = clone(loc)
        assert type(c) is cls and c.get_params().keys() == params.keys()
        assert cls.name == name
    with pytest.raises(ValueError, match="unknown localizer"):
        make_localizer("nope")
    with pytest.raises(ValueError, match="no setting"):
        make_localizer("mle").set_params(bogus=1)
    with pytest.raises(TypeError, match="scenario"):
        make_localizer("mle").fit(lattice_flight(0).frames)


def test_pose_aware_crlb_reduces_to_poisson_crlb_and_grows_with_pose_variance():
    from estimator.localizers.mle import pose_aware_crlb
    from estimator.mle import crlb
    from estimator.model import MeasurementModel

    src = (4.3, 3.7, 0.0, 1600.0)
    theta = {"x": 4.3, "y": 3.7, "cps_at_1m": 1600.0, "background_cps": 30.0}
    exact = dwell_frames(lattice_points((4.3, 3.7)), [src], 30.0, dwell_s=10.0, exact=True)
    noisy = dwell_frames(lattice_points((4.3, 3.7)), [src], 30.0, dwell_s=10.0, exact=True, pose_sd=0.04)
    model = MeasurementModel(scenario_for())
    np.testing.assert_allclose(pose_aware_crlb(model, theta, exact), crlb(model, theta, exact), rtol=1e-6)
    c0, c1 = crlb(model, theta, noisy), pose_aware_crlb(model, theta, noisy)
    assert np.all(np.diag(c1) >= np.diag(c0)) and c1[0, 0] > 1.5 * c0[0, 0]


def test_landmark_free_drift_bound():
    """Without walls a pose offset and a source translation are the same thing, so the landmark-free
    bound is the detector-offset bound; behind a mapped wall the wall's edges would pin the pose, and the
    landmark-free bound claims none of that (it is larger, never smaller)."""
    from estimator.localizers.mle import pose_aware_crlb
    from estimator.model import MeasurementModel
    from radseek.dataset import Wall

    src = (4.3, 3.7, 0.0, 1600.0)
    theta = {"x": 4.3, "y": 3.7, "cps_at_1m": 1600.0, "background_cps": 30.0}
    noisy = dwell_frames(lattice_points((4.3, 3.7)), [src], 30.0, dwell_s=10.0, exact=True, pose_sd=0.04)
    free = MeasurementModel(scenario_for())
    np.testing.assert_allclose(pose_aware_crlb(free, theta, noisy, landmarks=False),
                               pose_aware_crlb(free, theta, noisy, landmarks=True), rtol=2e-3)
    wall = Wall(start=(4.6, 3.4), end=(4.6, 8.0), thickness=0.2, height=2.0)  # its end 0.4 m from the source
    walled = MeasurementModel(scenario_for(walls=[wall]), effects=("wall_attenuation",))
    th = {**theta, "wall_attenuation.mu_per_m": 3.0}
    c_free = pose_aware_crlb(walled, th, noisy, landmarks=False)[:2, :2]
    c_mark = pose_aware_crlb(walled, th, noisy, landmarks=True)[:2, :2]
    assert np.linalg.eigvalsh(c_free - c_mark).min() > -1e-12 and np.trace(c_free) > 1.2 * np.trace(c_mark)
