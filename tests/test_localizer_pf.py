"""Paper 000 SIR particle filter: resampler, convergence on the lattice replica, dead time, stopping rule."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.analytic_flights import dwell_frames, lattice_flight, lattice_points, scenario_for
from estimator.localizers import make_localizer
from estimator.localizers.particle_filter import low_variance_resample


def test_low_variance_resampler_counts_match_weights():
    rng = np.random.default_rng(0)
    w = rng.random(1000) ** 3
    w /= w.sum()
    idx = low_variance_resample(w, rng)
    assert len(idx) == 1000
    counts = np.bincount(idx, minlength=1000)
    # systematic resampling: every particle gets floor or ceil of N w_i copies
    assert np.all(np.abs(counts - 1000 * w) < 1.0 + 1e-9)


def test_pf_converges_on_lattice_replica():
    errs = []
    for seed in range(3):
        ds = lattice_flight(seed, pose_sd=0.03)
        pf = make_localizer("pf", n_particles=20_000, seed=seed).fit(ds)
        tr = ds.truth.sources[0]
        errs.append(np.hypot(pf.position_[0] - tr.x, pf.position_[1] - tr.y))
        assert pf.sources_[0]["cps_at_1m"] == pytest.approx(tr.cps_at_1m, rel=0.15)
        assert pf.background_ == pytest.approx(30.0, rel=0.15)
    assert max(errs) < 0.25
    h = pf.history_
    assert h[-1]["total_variance"] < h[0]["total_variance"] / 100
    assert h[-1]["entropy"] < h[0]["entropy"]
    assert pf.crlb_.shape == (4, 4) and np.all(np.diag(pf.crlb_)[[0, 1, 3]] > 0)


def test_dead_time_in_likelihood_removes_intensity_bias():
    tau = 2e-5
    src = (5.0, 4.0, 0.0, 30000.0)
    pts = lattice_points((5.0, 4.0), height=1.2, spacing=1.0)
    frames = dwell_frames(pts, [src], 30.0, dwell_s=8.0, rng=np.random.default_rng(3), tau_s=tau)
    scen = scenario_for()
    kw = dict(n_particles=20_000, activity_scale=20000.0)
    naive = make_localizer("pf", **kw).fit(frames, scen)
    aware = make_localizer("pf", dead_time_s=tau, **kw).fit(frames, scen)
    assert aware.sources_[0]["cps_at_1m"] == pytest.approx(30000, rel=0.08)
    assert naive.sources_[0]["cps_at_1m"] < 0.9 * 30000


def test_sequential_updates_and_stop_on_total_variance():
    ds = lattice_flight(4)
    half = len(ds.frames) // 2
    m = np.arange(len(ds.frames)) < half
    pf = make_localizer("pf", n_particles=5000, seed=1)
    pf.partial_fit(ds.frames.select(m), ds.scenario).partial_fit(ds.frames.select(~m))
    full = make_localizer("pf", n_particles=5000, seed=1).fit(ds)
    assert pf.n_updates_ >= full.n_updates_ - 1
    assert np.linalg.norm(pf.position_ - full.position_) < 0.1
    stop = make_localizer("pf", n_particles=5000, stop_variance=0.5).fit(ds)
    assert stop.converged_ and stop.n_updates_ < full.n_updates_
    assert stop.history_[-1]["total_variance"] < 0.5


def test_update_api_and_gaussian_likelihood():
    scen = scenario_for()
    pf = make_localizer("pf", n_particles=2000, likelihood="gaussian").initialize(scen)
    pf.update([5.0, 4.0, 1.5], counts=100.0, duration=1.0)
    assert pf.n_updates_ == 1 and abs(pf.weights_.sum() - 1) < 1e-9
    with pytest.raises(ValueError):
        make_localizer("pf", likelihood="nope").initialize(scen)


def test_crlb_is_the_inverse_fisher_of_the_measurements():
    """crlb_ is the Poisson CRLB (paper 004 eq. 5.3) of the filter's chunks at its estimate, with dead time."""
    tau = 2e-5
    pts = lattice_points((5.0, 4.0))
    frames = dwell_frames(pts, [(5.0, 4.0, 0.0, 1600.0)], 30.0, dwell_s=5.0, frame_s=1.0,
                          rng=np.random.default_rng(0), tau_s=tau)
    pf = make_localizer("pf", n_particles=5000, dead_time_s=tau).fit(frames, scenario_for())
    s = pf.sources_[0]
    theta = np.array([s["x"], s["y"], s["cps_at_1m"], pf.background_])
    pos, dur = frames.positions, frames.duration  # chunk_s = frame_s: one measurement per frame

    def mu(th):  # analytic expected counts (paper 000 eq. 9-10)
        n = th[2] / (((pos[:, :2] - th[:2]) ** 2).sum(1) + pos[:, 2] ** 2) + th[3]
        return dur * n * np.exp(-n * tau)

    eps = np.array([1e-5, 1e-5, 1e-3, 1e-4])
    jac = np.stack([(mu(theta + e) - mu(theta - e)) / (2 * e.sum()) for e in np.diag(eps)], axis=1)
    bound = np.linalg.inv((jac / mu(theta)[:, None]).T @ jac)
    sel = [0, 1, 3]  # x, y, A of (x, y, z, A); the background is profiled in the 4 x 4 inverse
    np.testing.assert_allclose(pf.crlb_[np.ix_(sel, sel)], bound[:3, :3], rtol=1e-4)


@pytest.mark.parametrize("setting", [dict(dead_time_s=1e-4),
                                     dict(effects=("dead_time",), effect_params={"dead_time.tau_s": 1e-4}),
                                     dict(dead_time_s=1e-4, effects=("dead_time",)),
                                     dict(dead_time_s=1e-4, effects=("dead_time",),
                                          effect_params={"dead_time.tau_s": 1e-4}),
                                     dict(dead_time_s=1e-4, effects=("air_attenuation",),
                                          effect_params={"air_attenuation.mu_per_m": 0.0})])
def test_dead_time_is_applied_once(setting):
    """Every way of asking for dead time gives paper 000 eq. 10 once: T lambda_T exp(-tau lambda_T)."""
    tau, pos, dur = 1e-4, np.array([5.0, 4.0, 1.0]), 2.0
    pf = make_localizer("pf", n_particles=1000, **setting).initialize(scenario_for())
    x, y, a, b = pf.particles_.T
    lam_t = a / ((x - pos[0]) ** 2 + (y - pos[1]) ** 2 + pos[2] ** 2) + b
    np.testing.assert_allclose(pf.expected_counts(pos, dur), dur * lam_t * np.exp(-tau * lam_t), rtol=1e-9)


def test_dead_time_given_twice_must_agree():
    with pytest.raises(ValueError, match="same dead time"):
        make_localizer("pf", dead_time_s=1e-4, effects=("dead_time",),
                       effect_params={"dead_time.tau_s": 2e-4}).initialize(scenario_for())


def test_model_effects_in_the_likelihood():
    """effects= routes the likelihood through estimator.model.MeasurementModel (here: its dead-time part)."""
    tau = 2e-5
    src = (5.0, 4.0, 0.0, 30000.0)
    pts = lattice_points((5.0, 4.0), height=1.2, spacing=1.0)
    frames = dwell_frames(pts, [src], 30.0, dwell_s=8.0, rng=np.random.default_rng(3), tau_s=tau)
    scen = scenario_for()
    via_model = make_localizer("pf", n_particles=20_000, activity_scale=20000.0, effects=("dead_time",),
                               effect_params={"dead_time.tau_s": tau}).fit(frames, scen)
    assert via_model.sources_[0]["cps_at_1m"] == pytest.approx(30000, rel=0.08)
    assert np.hypot(via_model.position_[0] - 5.0, via_model.position_[1] - 4.0) < 0.1
    with pytest.raises(ValueError, match="second_source"):
        make_localizer("pf", effects=("second_source",)).fit(frames, scen)
    with pytest.raises(ValueError, match="effect_params"):
        make_localizer("pf", effects=("dead_time",), effect_params={"bogus": 1.0}).fit(frames, scen)


def test_tempering_survives_an_ambiguous_start():
    """Three collinear first dwells leave a mirror-symmetric posterior; tempered updates keep both modes."""
    src = (5.0, 4.0, 0.0, 2000.0)
    pts = np.array([[x, y, 1.5] for x in (3.5, 5.0, 6.5) for y in (2.5, 4.0, 6.0)])
    errs = []
    for seed in range(3):
        frames = dwell_frames(pts, [src], 30.0, dwell_s=10.0, rng=np.random.default_rng(seed))
        pf = make_localizer("pf", n_particles=20_000, seed=seed).fit(frames, scenario_for())
        errs.append(np.hypot(pf.position_[0] - 5.0, pf.position_[1] - 4.0))
    assert max(errs) < 0.3
