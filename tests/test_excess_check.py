"""A one-source estimate whose background stands above the operator's pre-flight value: the excess as a z-score
(analytic cases), the second-source test it sends, and the check dwell the search flies before it stops
(the two-source scene, information planner, seed 0, in-process flights)."""

import math

import numpy as np
import pytest

from detector_fw_sim.scene import load_scene
from estimator.inflight import BACKGROUND_EXCESS_Z, BACKGROUND_PRIOR_REL, background_excess_z
from launch.offline import fly_offline
from mission.search import Outcome, SearchConfig, unseen_flux

SECOND = np.array([8.1, 3.0])  # detector_fw_sim/scenes/two-source.toml: the 1300 cps second source


def test_the_excess_is_counted_in_the_fit_and_prior_sds_together():
    prior = 40.0
    sd = math.hypot(3.0, BACKGROUND_PRIOR_REL * prior)
    assert background_excess_z(50.0, 3.0, prior) == pytest.approx(10.0 / sd)
    assert background_excess_z(30.0, 2.0, 30.0) == 0.0
    assert background_excess_z(20.0, 0.0, 30.0) == pytest.approx(-10.0 / 3.0)  # a deficit is negative
    assert math.isnan(background_excess_z(50.0, math.nan, 30.0))  # a fit without an error says nothing
    assert math.isnan(background_excess_z(5.0, 0.5, 0.0))  # an operator's 0 is no pre-flight value


@pytest.fixture(scope="module")
def flights():
    scene = load_scene("two-source")
    return {n: fly_offline(scene, SearchConfig(strategy="info", excess_checks=n), seed=0) for n in (0, 2)}


def test_without_a_check_the_hugging_dwells_keep_one_source_and_report_the_excess(flights):
    r = flights[0]
    final = r.brain.estimator.estimate
    assert final["effects"] == []
    assert final["background_excess_z"] > BACKGROUND_EXCESS_Z  # still said, in the record
    assert not any(d.reason.startswith("check:") for d in r.decisions)
    assert r.brain.check_dwells == 0


def test_a_check_dwell_where_no_dwell_was_lets_the_second_source_show(flights):
    r, without = flights[2], flights[0]
    checks = [i for i, d in enumerate(r.decisions) if d.reason.startswith("check:")]
    assert len(checks) == r.brain.check_dwells >= 1
    # the check dwell lies check_distance_m from the estimate it was planned from, away from every earlier dwell,
    # towards where a source the flight had not seen would give the most flux: here towards the second source
    k = checks[0]  # decision k (after k dwells) sends the vehicle to dwell point k
    point = r.dwell_positions[k, :2]
    est = next(e for e in r.brain.estimator.estimates if e["dwell"] == k)
    assert np.linalg.norm(point - [est["x"], est["y"]]) == pytest.approx(3.0, abs=0.3)
    assert np.min(np.linalg.norm(r.dwell_positions[:k, :2] - point, axis=1)) > 1.5
    assert np.linalg.norm(point - SECOND) < np.linalg.norm(np.array([est["x"], est["y"]]) - SECOND) - 2.0
    final = r.brain.estimator.estimate
    assert final["effects"] == ["second_source"]
    found = np.array([final["params"]["second_source.x"], final["params"]["second_source.y"]])
    assert np.linalg.norm(found - SECOND) < 1.5
    assert r.error_m < without.error_m
    # the check spent no search budget and the search still ended found
    assert r.decisions[-1].outcome in (Outcome.FOUND, Outcome.DRIFT_LIMITED)
    assert r.brain._budget_dwells() <= r.brain.search_dwells - r.brain.check_dwells


def test_a_negative_check_budget_is_refused():
    with pytest.raises(ValueError, match="excess_checks"):
        SearchConfig(excess_checks=-1)


def test_the_excess_is_said_where_a_one_source_estimate_is_read(flights, tmp_path, capsys):
    from estimator.inflight import excess_warning
    from radseek_cli.replay_cli import main as replay_main
    from radseek_io.dataset import write_dataset

    prior = flights[0].dataset.scenario.background_cps
    said = excess_warning(flights[0].brain.estimator.estimate, prior)
    assert said is not None and "sd above the operator's 30 cps" in said
    assert excess_warning(flights[2].brain.estimator.estimate, prior) is None  # the second source holds the flux
    # radseek replay reproduces the flight's estimates (the check is the search's, not the estimator's) and says it
    ds = flights[0].dataset
    path = write_dataset(tmp_path / "flight", ds.frames, ds.scenario, ds.truth)
    assert replay_main([str(path)]) == 0
    assert "THE BACKGROUND IS TOO HIGH HERE" in capsys.readouterr().out


def test_no_check_is_flown_past_the_battery_budget():
    """With the battery budget at the dwells the checked flight had flown before its first check, the search
    stops there: a check would be dwell max_dwells + 1."""
    scene = load_scene("two-source")
    checked = fly_offline(scene, SearchConfig(strategy="info", excess_checks=2), seed=0)
    first = next(i for i, d in enumerate(checked.decisions) if d.reason.startswith("check:"))
    r = fly_offline(scene, SearchConfig(strategy="info", excess_checks=2, max_dwells=first), seed=0)
    assert r.brain.check_dwells == 0
    assert len(r.dwell_positions) == first
    assert r.decisions[-1].outcome in (Outcome.FOUND, Outcome.DRIFT_LIMITED)


def test_the_check_looks_where_an_unseen_source_could_hide():
    """``unseen_flux``: a flight that flew only the west half of a 10 x 8 m room (x <= 4) could have missed a source
    in the east half, the farther east the stronger: a point 3 m east of (4, 4) sees more of it than one 3 m west,
    north or south; a flight flown symmetrically about x = 5 scores mirror points alike; one that flew the whole
    room leaves less to see everywhere."""
    lo, hi = np.array([0.0, 0.0]), np.array([10.0, 8.0])
    west = np.array([[x, y, 1.5] for x in np.linspace(0.0, 4.0, 9) for y in np.linspace(0.0, 8.0, 9)])
    points = np.array([[7.0, 4.0, 1.5], [1.0, 4.0, 1.5], [4.0, 7.0, 1.5], [4.0, 1.0, 1.5]])
    score = unseen_flux(points, west, lo, hi, 0.0)
    assert np.argmax(score) == 0 and score[0] > 2 * score[1:].max()
    assert score[2] == pytest.approx(score[3], rel=1e-9)  # the room and the flight are symmetric about y = 4
    both = np.vstack([west, west * [-1, 1, 1] + [10.0, 0.0, 0.0]])
    mirror = unseen_flux(np.array([[7.0, 4.0, 1.5], [3.0, 4.0, 1.5]]), both, lo, hi, 0.0)
    assert mirror[0] == pytest.approx(mirror[1], rel=1e-9)
    everywhere = np.array([[x, y, 1.5] for x in np.linspace(0.0, 10.0, 21) for y in np.linspace(0.0, 8.0, 17)])
    assert np.all(unseen_flux(points, everywhere, lo, hi, 0.0) < score)
    # a frame recorded without a pose (NaN) was not flown anywhere
    np.testing.assert_array_equal(unseen_flux(points, np.vstack([west, np.full((1, 3), np.nan)]), lo, hi, 0.0), score)
