"""Paper 003 sphere intersection: exact spheres meet at the source; outliers behind walls are dropped."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.analytic_flights import dwell_frames, lattice_flight, scenario_for
from estimator.localizers import clone, make_localizer
from estimator.localizers.sphere_intersection import eq5_error, intersection_points
from radseek.dataset import Wall


def test_three_exact_spheres_meet_at_source():
    src = np.array([4.0, 3.0, 0.0])
    s = 1500.0
    centers = np.array([[2.0, 2.0, 1.5], [5.5, 2.0, 1.5], [4.0, 5.0, 1.5]])
    lam = s / ((centers - src) ** 2).sum(axis=1)
    pts, ss = intersection_points(centers, lam, np.array([s]), z_s=0.0)
    # each pair meets in two points on the floor; the source is common to all three pairs
    hits = np.linalg.norm(pts - src, axis=1) < 1e-6
    assert hits.sum() == 3
    assert np.all(ss == s)
    # 3-D circles pass through the source too
    pts3, _ = intersection_points(centers, lam, np.array([s]), z_s=None, n_circle=3600)
    assert np.min(np.linalg.norm(pts3 - src, axis=1)) < 0.01


def test_exact_readings_localize_source():
    src = (4.3, 3.7, 0.0, 1600.0)
    pts = np.array([[1, 1, 1.5], [3, 2.5, 1.5], [5.5, 2.5, 1.5], [3, 5, 1.4], [5.5, 5, 1.6], [4.3, 2.0, 1.5]])
    frames = dwell_frames(pts, [src], 30.0, dwell_s=100.0, exact=True)
    loc = make_localizer("sphere", n_spheres=600, relative_error=0.01, alpha=0.8).fit(frames, scenario_for())
    assert np.linalg.norm(loc.position_[:2] - src[:2]) < 0.05
    assert loc.sources_[0]["cps_at_1m"] == pytest.approx(1600, rel=0.03)
    assert eq5_error(np.array(src[:3]), 1600.0, pts, 1600.0 / ((pts - src[:3]) ** 2).sum(1)) == 0.0


def test_lattice_replica_poisson():
    errs = []
    for seed in range(5):
        ds = lattice_flight(seed)
        loc = make_localizer("sphere").fit(ds)
        tr = ds.truth.sources[0]
        errs.append(np.hypot(loc.position_[0] - tr.x, loc.position_[1] - tr.y))
    assert np.median(errs) < 0.3
    assert loc.covariance_.shape == (4, 4) and loc.crlb_ is None


def test_occluded_disagreeing_dwell_is_dropped():
    src = (5.0, 4.0, 0.0, 2000.0)
    pts = np.array([[3.5, 2.5, 1.5], [6.5, 2.5, 1.5], [3.5, 5.5, 1.5], [5.0, 2.3, 1.5], [6.5, 5.5, 1.5]])
    frames = dwell_frames(pts, [src], 30.0, dwell_s=20.0, rng=np.random.default_rng(1))
    # the last dwell reads 30 % of what it should (a wall between it and the source)
    last = frames.dwell == 4
    counts = frames.counts.copy()
    counts[last] = np.random.default_rng(2).poisson(counts[last] * 0.3)
    frames = type(frames)(**{**{k: getattr(frames, k) for k in frames.__dataclass_fields__}, "counts": counts})
    wall = Wall((5.6, 4.6), (7.0, 4.6), 0.2, 3.0)
    scen = scenario_for(walls=(wall,))
    loc = make_localizer("sphere").fit(frames, scen)
    assert loc.info_["dwells_dropped"] == [4]
    assert np.linalg.norm(loc.position_[:2] - src[:2]) < 0.3
    # without a mapped wall the occluded-only rule keeps it; "always" drops it anyway
    assert make_localizer("sphere").fit(frames, scenario_for()).info_["dwells_dropped"] == []
    assert 4 in make_localizer("sphere", drop_outliers="always").fit(frames, scenario_for()).info_["dwells_dropped"]


def test_snaps_to_nearest_occupied_cell_and_clone():
    ds = lattice_flight(3)
    tr = ds.truth.sources[0]
    cells = np.array([[tr.x + 0.1, tr.y, 0.05], [0.0, 0.0, 0.05]])
    loc = make_localizer("sphere", occupancy=cells).fit(ds)
    np.testing.assert_allclose(loc.position_, cells[0])
    c = clone(loc)
    assert c.get_params()["alpha"] == loc.alpha and not hasattr(c, "sources_")


def test_too_few_readings_raises():
    frames = dwell_frames(np.array([[1, 1, 1.5], [9, 7, 1.5]]), [(5, 4, 0, 100.0)], 30.0, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="3 dwell points"):
        make_localizer("sphere").fit(frames, scenario_for())


def test_partial_fit_of_a_batch_method_refits_on_everything_seen():
    ds = lattice_flight(2)
    m = np.arange(len(ds.frames)) < len(ds.frames) // 2
    loc = make_localizer("sphere").partial_fit(ds.frames.select(m), ds.scenario).partial_fit(ds.frames.select(~m))
    full = make_localizer("sphere").fit(ds)
    np.testing.assert_allclose(loc.position_, full.position_)
    assert len(loc.frames_seen_) == len(ds.frames)
    est = loc.to_estimate(t=3.0)
    assert est.method == "sphere" and est.sources[0]["cps_at_1m"] == loc.sources_[0]["cps_at_1m"]
