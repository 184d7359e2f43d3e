"""radseek diagnose on flights from the independent forward model (benchmarks.forward2): seeded, with bounds from
the statistics, no wall-clock assertions. The full power curves and false-alarm rate are
``python -m benchmarks.diagnose_evaluate`` (docs/diagnose-evaluation.md)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from benchmarks.forward2 import FlightSpec, simulate
from estimator.diagnose.dispersion import fit_dispersion
from estimator.diagnose.runner import diagnose
from estimator.diagnose.threads import blas_threads
from estimator.spectral import SpectralModel
from radseek.dataset import Frames
from reporting.truth_errors import score_diagnosis


def _frames(n: np.ndarray, dwell: np.ndarray) -> Frames:
    z = np.zeros(len(n))
    counts = np.zeros((len(n), 32), dtype=np.int64)
    counts[:, 0] = n
    return Frames(t=np.arange(len(n)) * 0.1 + 0.1, duration=z + 0.1, x=z, y=z, z=z, yaw=z, var_x=z, var_y=z, var_z=z,
                  dwell=dwell, counts=counts)


def test_over_dispersion_test_is_calibrated_under_a_wrong_mean_and_finds_real_scatter():
    rng = np.random.default_rng(7)
    N = 1200
    t = np.arange(N)
    mu = 40.0 * np.exp(np.sin(t / 60))
    wrong = mu * (1 + 0.25 * np.cos(t / 40))  # a 25 % smooth mean misfit, as a missing wall or source leaves
    dwell = t // 80
    crit = stats.chi2.isf(2 * 0.01, 1)  # 1/2 chi2_0 + 1/2 chi2_1 at p = 0.01
    alarms = sum(fit_dispersion(_frames(rng.poisson(mu), dwell), wrong).lr > crit for _ in range(40))
    assert alarms <= 3  # binomial(40, 0.01): P(>= 4) < 1e-3
    g = rng.gamma(1 / 0.1**2, 0.1**2, N)
    fit = fit_dispersion(_frames(rng.poisson(mu * g), dwell), wrong)
    assert fit.lr > 30 and abs(fit.rel_sd - 0.1) < 4 * fit.error


@pytest.mark.slow
def test_null_independent_flight_names_nothing():
    ds = simulate(FlightSpec("lattice", {}, crystal="fill", dwell_s=6.0, scatter=0.02), seed=501)
    d = diagnose(ds, quiet=True, n_starts=2)
    assert d.selection.missing == []


@pytest.mark.slow
def test_over_dispersion_is_named_and_not_taken_for_geometry():
    ds = simulate(FlightSpec("lattice", {"over_dispersion": {"rel_sd": 0.15}}, crystal="real", dwell_s=6.0), seed=502)
    d = diagnose(ds, quiet=True, n_starts=2)
    assert d.selection.missing == ["over_dispersion"]
    top = d.selection.first[0]
    assert top.explains == "frame-to-frame scatter"
    r, e = top.params["over_dispersion.rel_sd"], top.errors["over_dispersion.rel_sd"]
    assert abs(r - 0.15) < 4 * e
    a = d.after
    assert abs(a.gof.deviance_per_dof - a.gof.expected_per_dof) < 4 * a.gof.sd_per_dof  # the variance term


@pytest.mark.slow
def test_strong_wall_on_an_l_shape_is_named_and_lowers_the_source_error():
    ds = simulate(FlightSpec("lshape", {"wall_attenuation": {"mu_per_m": 3.0}}, crystal="wide", dwell_s=6.0), seed=503)
    d = score_diagnosis(diagnose(ds, quiet=True, n_starts=2), ds.truth)
    assert d.selection.missing[:1] == ["wall_attenuation"]
    assert d.after is not None and d.after.source_error_m <= d.current.source_error_m + 0.01
    mu, err = d.selection.first[0].params["wall_attenuation.mu_per_m"], d.selection.first[0].errors[
        "wall_attenuation.mu_per_m"]
    assert abs(mu - 3.0) < 5 * err + 0.3


@pytest.mark.slow
def test_gain_drift_measured_on_a_crystal_unlike_the_templates_with_a_changing_shape():
    """The issue-14 miss: a crystal with more scatter fill, a spectrum whose shape changes with distance (outdoor
    buildup). No drift -> no evidence; 0.9 %/min -> found, not scaled away by the shape change."""
    with blas_threads(1):
        null = simulate(FlightSpec("outdoor", {}, crystal="fill", scatter=0.05), seed=4)
        f0 = SpectralModel(null.scenario.channel_edges_keV).fit(null.frames)
        drift = simulate(FlightSpec("outdoor", {"gain_drift": {"percent_per_min": 0.9}}, crystal="fill",
                                    scatter=0.05), seed=4)
        f1 = SpectralModel(drift.scenario.channel_edges_keV).fit(drift.frames)
    assert f0.log10_p > -2  # p > 0.01 with no drift
    assert f1.log10_p < -6 and 0.4 < f1.percent_per_min < 1.3
    assert f1.dispersion < 1.5  # the mismatch template took the shape change, not the over-dispersion scale
