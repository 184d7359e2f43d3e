"""Every localizer is held to the Cramér-Rao bound and to a goodness of fit, as the MLE holds itself
(``localize_cli.hold_to_the_bound``, ``estimator.mle.check_estimate``)."""

import math

import numpy as np
import pytest

from estimator.localizers import make_localizer
from radseek_cli.localize_cli import hold_to_the_bound
from radseek_io.dataset import read_dataset


def _result(loc) -> dict:
    c = np.asarray(loc.covariance_)
    return {"std": [[float(np.sqrt(max(c[k, k], 0.0))) for k in range(4)]], "crlb_std": None, "info": {}}


def test_an_overconfident_spread_is_raised_to_the_bound_and_said(shared_datasets):
    ds = read_dataset(shared_datasets / "lattice-clean")
    loc = make_localizer("pf", seed=0).fit(ds)
    loc.covariance_ = np.asarray(loc.covariance_) * 1e-6  # the fault: a cloud collapsed 1000x in spread
    res = _result(loc)
    warn = hold_to_the_bound(loc, ds.scenario, ds.frames, res, "pf")
    assert len(warn) == 1 and "Cramér-Rao" in warn[0]
    sd, cr = res["std"][0], res["crlb_std"][0]
    for j in (0, 1, 3):
        assert sd[j] == pytest.approx(cr[j]) and sd[j] > 100 * res["std_method"][0][j]
    # the right model on a clean flight: its fit is adequate at the filter's estimate
    assert res["info"]["p_value"] > 1e-3


def test_a_method_without_its_own_fit_check_gets_one_and_a_misfit_shows(shared_datasets):
    """lattice-wall's walls are in scenario.json, but a filter run without wall_attenuation does not model them:
    p < 0.001 at its estimate (the CLI then warns as it does for the MLE)."""
    ds = read_dataset(shared_datasets / "lattice-wall")
    loc = make_localizer("pf", seed=0).fit(ds)
    res = _result(loc)
    hold_to_the_bound(loc, ds.scenario, ds.frames, res, "pf")
    assert res["info"]["p_value"] < 1e-3
    assert res["info"]["deviance_per_dof"] > 1.5
    assert all(math.isfinite(v) for v in res["std"][0])
