"""A second source's location is not identified by the fit without it: a candidate fit starts both at the
largest residual excess and at its best grid cell (``estimator.mle.fit(second_grid=True)``), one fit whose screen
searches only the better basin in full."""

import numpy as np
import pytest

from estimator import mle
from estimator.mle import SCREEN_APART_M, fit
from estimator.model import MeasurementModel
from tests.test_mle import SCEN, TRUE, lattice_frames, with_counts

SECOND = {"second_source.x": 7.5, "second_source.y": 2.5, "second_source.cps_at_1m": 1500.0}


def _two_sources(seed):
    """The 9-point lattice over a 1600 cps source, a 1500 cps second source 4.3 m away, 5 cm pose error per dwell."""
    rng = np.random.default_rng(seed)
    f, off = lattice_frames(rng, var=0.05**2, offsets_sd=0.05)
    m = MeasurementModel(SCEN, ("second_source",))
    mu = m.expected_counts({**m.defaults(), **TRUE, **SECOND}, f, offsets=-off)
    return m, with_counts(f, rng.poisson(mu))


def test_two_minima_with_the_second_source_in_two_places_are_two_basins():
    a = {"x": 4.3, "y": 5.6, "second_source.x": 7.5, "second_source.y": 2.5}
    b = {**a, "second_source.x": 8.5}
    assert mle._distance(a, b) == pytest.approx(1.0)
    assert mle._distance(a, {**a, "x": 4.4}) == pytest.approx(0.1)
    assert mle._distance({"x": 0.0, "y": 0.0}, {"x": 0.3, "y": 0.4}) == pytest.approx(0.5)
    assert mle._distance(a, b) > SCREEN_APART_M


@pytest.mark.parametrize("seed", [0, 1])
def test_the_fit_screens_the_given_start_and_the_grid_cell_and_is_no_worse_than_either_alone(seed, monkeypatch):
    """The fit replaces two candidate fits (one from the residual excess, one from the grid; each searched in full
    before): the screen gets the given start and the second source's best grid cell, and the fit ends at least
    as low (-log L within 0.05) as either start searched alone, and at the truth-started fit's minimum."""
    m, f = _two_sources(seed)
    wrong = {**m.defaults(), **TRUE, "second_source.x": 1.0, "second_source.y": 9.0,
             "second_source.cps_at_1m": 20.0}
    screen, seen = mle._screen, []
    monkeypatch.setattr(mle, "_screen", lambda model, frames, names, fixed, starts, **k:
                        seen.append(starts) or screen(model, frames, names, fixed, starts, **k))
    both = fit(m, f, n_starts=2, init=wrong, second_grid=True)
    cell = mle.second_source_starts(m, f, wrong, n_best=1)[0]
    assert len(seen[0]) == 2
    assert seen[0][0]["second_source.x"] == 1.0 and seen[0][0]["second_source.y"] == 9.0
    assert all(seen[0][1][k] == pytest.approx(v) for k, v in cell.items())
    alone = fit(m, f, n_starts=1, init=wrong)
    grid = fit(m, f, n_starts=1, init={k: v for k, v in wrong.items() if not k.startswith("second")})
    right = fit(m, f, n_starts=1, init={**m.defaults(), **TRUE, **SECOND})
    assert both.converged
    assert both.nll <= min(alone.nll, grid.nll) + 0.05
    assert both.nll <= right.nll + 0.05
    for k in ("second_source.x", "second_source.y"):
        assert abs(both.values[k] - right.values[k]) < 3 * right.errors[k]
