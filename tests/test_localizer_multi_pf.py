"""Paper 004 multi-source particle filter: eq. 3.11 / 5.19 intensities, eq. 4.16 separation, two sources."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.analytic_flights import dwell_frames, expected_total, lattice_flight, scenario_for
from estimator.localizers import make_localizer
from estimator.localizers.multi_source_pf import landmark_intensity, separate_intensities
from radseek.dataset import Wall
from radseek.geometry import path_lengths
from radseek_io.truth import read_dataset_with_truth


def test_eq_3_11_exact_intensity():
    g = np.array([[1 / 4.0, 1 / 9.0, 1 / 2.0]])
    z = 1500.0 * g[0] + 30.0
    assert landmark_intensity(z, g, 30.0)[0] == pytest.approx(1500.0)


def test_eq_4_16_separation_inverts_mixing():
    pos = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 3.0]])
    true = np.array([1000.0, 500.0, 800.0])
    d2 = ((pos[:, None] - pos[None]) ** 2).sum(-1)
    mix = np.where(np.eye(3, dtype=bool), 1.0, 1.0 / np.where(d2 > 0, d2, 1.0))
    apparent = mix @ true + 30.0
    np.testing.assert_allclose(separate_intensities(pos, apparent, 30.0), true)


def test_single_source_lattice():
    ds = lattice_flight(7, pose_sd=0.03)
    loc = make_localizer("multi-pf", n_particles=2000).fit(ds)
    tr = ds.truth.sources[0]
    assert len(loc.sources_) == 1
    assert np.hypot(loc.position_[0] - tr.x, loc.position_[1] - tr.y) < 0.2
    assert loc.sources_[0]["cps_at_1m"] == pytest.approx(tr.cps_at_1m, rel=0.1)


def test_two_sources_shared_dataset(shared_datasets):
    """Both sources found (sequential discovery + subtraction); the first is pulled towards the second.

    Known weakness (docs/localizers.md): eq. 3.11 fits the first source as if it were alone, so with
    two comparable sources 4.9 m apart its position lands ~1.4 m off, between them.
    """
    ds = read_dataset_with_truth(shared_datasets / "two-sources")
    loc = make_localizer("multi-pf").fit(ds)
    assert len(loc.sources_) == 2
    truth = [(s.x, s.y) for s in ds.truth.all_sources()]
    errs = sorted(min(np.hypot(s["x"] - tx, s["y"] - ty) for tx, ty in truth) for s in loc.sources_)
    assert errs[0] < 0.5 and errs[1] < 1.6
    assert loc.covariance_.shape == (8, 8)


def test_wall_attenuation_eq_5_19():
    mu = 3.0
    wall = Wall((3.0, 5.0), (7.0, 5.0), 0.2, 3.0)
    scen = scenario_for(walls=(wall,))
    src = np.array([5.0, 4.0, 0.0])
    pts = np.array([[x, y, 1.5] for x in (3.5, 5.0, 6.5) for y in (2.5, 4.0, 6.0)])
    lam = expected_total(pts, [(*src, 2000.0)], 0.0, 1.0) * np.exp(-mu * path_lengths(src, pts, scen.walls)) + 30
    rng = np.random.default_rng(4)
    frames = dwell_frames(pts, [(*src, 2000.0)], 30.0, dwell_s=10.0, rng=rng)
    counts = frames.counts.copy()
    for k in range(len(pts)):
        m = frames.dwell == k
        counts[m, 10] = rng.poisson(lam[k] * 0.1, m.sum())
    frames = type(frames)(**{**{k: getattr(frames, k) for k in frames.__dataclass_fields__}, "counts": counts})
    aware = make_localizer("multi-pf", n_particles=2000, wall_mu_per_m=mu, max_sources=1).fit(frames, scen)
    assert np.hypot(aware.position_[0] - 5.0, aware.position_[1] - 4.0) < 0.25
    assert aware.sources_[0]["cps_at_1m"] == pytest.approx(2000, rel=0.1)
