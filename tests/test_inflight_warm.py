"""A confident wall-free estimate is refitted from itself alone (estimator.inflight.WARM_SIGMA_M); the grid
starts come back only when that refit misfits. On the shared lattice-clean flight (an independent generator's
data, no walls)."""

import numpy as np
import pytest

from estimator.inflight import DEFAULT_SETTINGS, WARM_SIGMA_M, InflightEstimator
from radseek.dataset import read_dataset


@pytest.fixture(scope="module")
def lattice_clean(shared_datasets):
    return read_dataset(shared_datasets / "lattice-clean")


def _counting(monkeypatch, misfit):
    real_fit = InflightEstimator._fit
    calls = []

    def fit(self, frames, settings):
        loc = real_fit(self, frames, settings)
        calls.append(settings.get("n_starts"))
        if misfit["on"] and loc is not None:
            loc.info_["p_value"] = 1e-6
        return loc

    monkeypatch.setattr(InflightEstimator, "_fit", fit)
    return calls


@pytest.mark.parametrize("injected_misfit", [False, True])
def test_a_confident_estimate_is_refitted_from_itself(lattice_clean, monkeypatch, injected_misfit):
    ds = lattice_clean
    misfit = {"on": False}
    calls = _counting(monkeypatch, misfit)
    est = InflightEstimator(ds.scenario)
    dwells = np.unique(ds.frames.dwell[ds.frames.dwell >= 0])
    first = est.update(ds.frames.select(ds.frames.dwell <= dwells[-2]), dwell=len(dwells) - 1)
    assert calls == [DEFAULT_SETTINGS["n_starts"]]
    assert first["sigma_m"] < WARM_SIGMA_M and first["converged"]
    misfit["on"] = injected_misfit
    calls.clear()
    second = est.update(ds.frames, dwell=len(dwells))
    if injected_misfit:
        # the warm fit misfits: all starts, then (p < 0.01) the two-source fit
        assert calls[:2] == [1, DEFAULT_SETTINGS["n_starts"]]
    else:
        assert calls == [1]
        truth = ds.truth.sources[0]
        assert np.hypot(second["x"] - truth.x, second["y"] - truth.y) < 3 * second["sigma_m"]
