"""A confident wall-free estimate is refitted from itself alone (estimator.inflight.WARM_SIGMA_M); the grid
starts come back only when that refit misfits. On the shared lattice-clean flight (an independent generator's
data, no walls)."""

import numpy as np
import pytest

from estimator.inflight import DEFAULT_SETTINGS, WARM_SIGMA_M, WARM_WALLED_STARTS, InflightEstimator
from radseek_io.truth import read_dataset_with_truth


@pytest.fixture(scope="module")
def lattice_clean(shared_datasets):
    return read_dataset_with_truth(shared_datasets / "lattice-clean")


@pytest.mark.parametrize("injected_misfit", [False, True])
def test_a_confident_estimate_is_refitted_from_itself(lattice_clean, counted_fits, injected_misfit):
    ds = lattice_clean
    calls, misfit = counted_fits
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


def test_a_walled_estimate_is_refitted_from_itself_when_the_plain_fit_misfits(shared_datasets, monkeypatch):
    """The last estimate was walled; the new wall-free refit misfits and no recorded line of sight near the
    estimate crosses a wall (both injected): the walled model is refitted once, from the last walled estimate and
    the grid's best cells (WARM_WALLED_STARTS). The independent generator's lattice-wall."""
    ds = read_dataset_with_truth(shared_datasets / "lattice-wall")
    real_fit = InflightEstimator._fit
    calls: list[tuple[tuple[str, ...], int]] = []

    def fit(self, frames, settings):
        loc = real_fit(self, frames, settings)
        effects = tuple(settings.get("effects", ()))
        calls.append((effects, settings.get("n_starts")))
        if inject["on"] and loc is not None and not effects:
            loc.info_["p_value"] = 1e-6  # the fault: the wall-free refit misfits
        return loc

    inject = {"on": False}
    monkeypatch.setattr(InflightEstimator, "_fit", fit)
    est = InflightEstimator(ds.scenario)
    dwells = np.unique(ds.frames.dwell[ds.frames.dwell >= 0])
    first = est.update(ds.frames.select(ds.frames.dwell <= dwells[-2]), dwell=len(dwells) - 1)
    assert first is not None and "wall_attenuation" in first["effects"]
    inject["on"] = True
    monkeypatch.setattr(InflightEstimator, "_shadowed", lambda self, frames, source: False)
    calls.clear()
    second = est.update(ds.frames, dwell=len(dwells))
    assert calls == [((), 1), (("wall_attenuation",), WARM_WALLED_STARTS)]
    assert "wall_attenuation" in second["effects"]
    truth = ds.truth.sources[0]
    assert np.hypot(second["x"] - truth.x, second["y"] - truth.y) < 3 * second["sigma_m"]


def test_a_wall_free_estimate_the_walls_now_shadow_goes_straight_to_the_walled_fit(shared_datasets, monkeypatch):
    """The last estimate was wall-free (injected) and a recorded line of sight near it crosses a wall: the
    refit is the walled model with its starts, and no wall-free fit first (the shadow would discard it); only
    then one warm wall-free fit, which the walls' likelihood-ratio test (mu = 3 /m here) discards."""
    ds = read_dataset_with_truth(shared_datasets / "lattice-wall")
    real_fit = InflightEstimator._fit
    calls: list[tuple[tuple[str, ...], int]] = []

    def fit(self, frames, settings):
        calls.append((tuple(settings.get("effects", ())), settings.get("n_starts")))
        return real_fit(self, frames, settings)

    monkeypatch.setattr(InflightEstimator, "_fit", fit)
    est = InflightEstimator(ds.scenario)
    dwells = np.unique(ds.frames.dwell[ds.frames.dwell >= 0])
    first = est.update(ds.frames.select(ds.frames.dwell <= dwells[-2]), dwell=len(dwells) - 1)
    first["effects"] = []  # the fault: the last estimate is taken as wall-free
    assert est._shadowed(ds.frames, [first[k] for k in ("x", "y", "z")])
    calls.clear()
    second = est.update(ds.frames, dwell=len(dwells))
    assert calls == [(("wall_attenuation",), WARM_WALLED_STARTS), ((), 1)]
    assert second["effects"] == ["wall_attenuation"] and second["converged"]
    truth = ds.truth.sources[0]
    assert np.hypot(second["x"] - truth.x, second["y"] - truth.y) < 3 * second["sigma_m"]
