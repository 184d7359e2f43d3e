"""Allocation between vehicles (issue 18): analytic cases for the reservation geometry and the joint brain.

No two vehicles at one point, a minimum separation in the air, no paths that cross while both are flown.
"""

from __future__ import annotations

import numpy as np
import pytest

from detector_fw_sim.scene import load_scene
from mission.search import Outcome, Phase, SearchConfig, reproducible
from mission.team import MAX_VEHICLES, TeamBrain, TeamConfig, home_positions
from planner.allocation import clearance, pairwise_min_distance, path_clear, point_segment_distance, reservation
from planner.belief import SourceBelief

SEP = 1.0


def test_point_segment_distance_analytic():
    a, b = np.array([[0.0, 0.0], [1.0, 1.0]]), np.array([[2.0, 0.0], [1.0, 1.0]])  # a segment and a point
    d = point_segment_distance(np.array([[1.0, 1.0], [3.0, 0.0], [-1.0, 0.0]]), a, b)
    assert d[:, 0] == pytest.approx([1.0, 1.0, 1.0])  # above the middle, beyond either end
    assert d[:, 1] == pytest.approx([0.0, np.hypot(2, 1), np.hypot(2, 1)])


def test_crossing_paths_conflict_and_parallel_ones_do_not():
    theirs = np.array([[0.0, 0.0, 1.5], [4.0, 4.0, 1.5]])
    crossing = np.array([[0.0, 4.0, 1.5], [4.0, 0.0, 1.5]])
    assert not path_clear(crossing, [theirs], SEP)
    parallel = theirs + [0.0, 1.5, 0.0]  # 1.5 / sqrt(2) = 1.06 m apart
    assert path_clear(parallel, [theirs], SEP)
    assert not path_clear(theirs + [0.0, 1.3, 0.0], [theirs], SEP)  # 0.92 m apart
    # a path ending within the separation of a teammate's dwell point (no two at one point)
    assert not path_clear(np.array([[0.0, 0.0, 1.5], [3.5, 0.0, 1.5]]), [np.array([[4.0, 0.3, 1.5]])], SEP)
    assert clearance(np.array([[0.0, 0.0]]), []) == np.inf


def test_reservation_is_the_rest_of_the_path():
    path = np.array([[0.0, 0.0, 1.5], [2.0, 0.0, 1.5], [2.0, 2.0, 1.5]])
    r = reservation(path, np.array([2.0, 0.5, 1.5]))  # on the second leg
    np.testing.assert_allclose(r, [[2.0, 0.5, 1.5], [2.0, 2.0, 1.5]])
    np.testing.assert_allclose(reservation(None, np.array([1.0, 2.0, 1.5])), [[1.0, 2.0, 1.5]])


@pytest.mark.parametrize("n", [0, MAX_VEHICLES + 1])
def test_team_size_out_of_range_is_refused(n):
    with pytest.raises(ValueError, match="n_vehicles"):
        TeamConfig(n_vehicles=n)


def _searching_brain(n: int = 2) -> TeamBrain:
    scenario = load_scene("default").scenario()
    brain = TeamBrain(scenario, reproducible(SearchConfig()), TeamConfig(n_vehicles=n), seed=3)
    brain.phase = Phase.SEARCH
    brain._belief = SourceBelief(np.array([4.3, 3.7, 0.0]), np.diag([0.04, 0.04, 0.01]), 1600.0, 30.0)
    brain._sigma = 0.2
    return brain


def test_start_sends_vehicles_to_separate_frontiers():
    scenario = load_scene("default").scenario()
    team = TeamConfig(n_vehicles=3)
    brain = TeamBrain(scenario, reproducible(SearchConfig()), team, seed=0)
    homes = home_positions(scenario, team)
    assert pairwise_min_distance(homes) >= team.home_spacing_m
    reserved = {v: np.r_[homes[v], 1.5][None, :] for v in range(3)}
    for v in range(3):
        d = brain.start(np.r_[homes[v], 1.5, 0.0], v, reserved)
        assert d.plan is not None and d.phase is Phase.EXPLORE
        others = [r for u, r in reserved.items() if u != v]
        assert path_clear(d.plan.path, others, team.separation_m)
        reserved[v] = d.plan.path[:, :3]
    ends = np.array([r[-1] for r in reserved.values()])
    assert pairwise_min_distance(ends) >= team.separation_m  # no two at one point


def test_next_best_dwell_point_keeps_clear_of_a_teammate_at_the_best_one():
    brain = _searching_brain()
    current = np.array([1.0, 1.0, 1.5, 0.0])
    free = brain.replan(1, current, {})
    assert free.plan is not None
    best = free.plan.dwell_points[0, :3]
    # the teammate is dwelling at that very point now: vehicle 1 must go elsewhere, clear of it
    brain2 = _searching_brain()
    d = brain2.replan(1, current, {0: best[None, :]})
    assert d.plan is not None, d.reason
    assert np.linalg.norm(d.plan.dwell_points[0, :2] - best[:2]) >= SEP
    assert path_clear(d.plan.path, [best[None, :]], SEP)


def test_a_teammate_path_across_the_hall_is_never_crossed():
    brain = _searching_brain()
    wall_of_flight = np.array([[6.0, 0.0, 1.5], [6.0, 8.0, 1.5]])  # a teammate flying along x = 6
    for _ in range(3):
        d = brain.replan(1, np.array([8.5, 4.0, 1.5, np.pi]), {0: wall_of_flight})
        if d.plan is None:
            assert d.hold_s > 0  # nothing free: hold, never cross
            continue
        assert d.plan.path[:, 0].min() >= 6.0 + SEP - 1e-9  # stays on its own side of the teammate's path
        assert path_clear(d.plan.path, [wall_of_flight], SEP)


def test_no_free_path_means_hold_then_plan_again():
    brain = _searching_brain()
    # teammates all around: every path from (2, 2) meets one within 1 m
    ring = [np.array([[2.0 + 1.2 * np.cos(a), 2.0 + 1.2 * np.sin(a), 1.5]]) for a in np.linspace(0, 2 * np.pi, 13)]
    d = brain.replan(1, np.array([2.0, 2.0, 1.5, 0.0]), {u + 2: r for u, r in enumerate(ring)})
    assert d.plan is None and d.hold_s == brain.team.hold_s and not d.done
    d = brain.replan(1, np.array([2.0, 2.0, 1.5, 0.0]), {})
    assert d.plan is not None


def test_the_separation_widens_with_both_vehicles_drift():
    from planner.allocation import DRIFT_K, Reservation, required_clearance

    theirs = Reservation(np.array([[0.0, 0.0, 1.5]]), var_xy=0.01)
    path = np.array([[1.2, -1.0, 1.5], [1.2, 1.0, 1.5]])  # passes 1.2 m from the teammate
    assert path_clear(path, [theirs.path], SEP)  # estimated positions only: clear
    need = required_clearance(SEP, 0.01, 0.01)
    assert need == pytest.approx(SEP + DRIFT_K * np.sqrt(0.02))  # 1.42 m: 3 sigma of the drifts' difference
    assert not path_clear(path, [theirs], SEP, var_xy=0.01)
    assert path_clear(path + [0.3, 0.0, 0.0], [theirs], SEP, var_xy=0.01)  # 1.5 m: clear of the drift margin too
    brain = _searching_brain()
    brain.set_pose_variance(1, 0.01, 0.001)
    assert brain.var_at_end(1, path) == pytest.approx(0.01 + 0.001 * 2.0)  # grows with the 2 m flown


def test_a_vehicle_boxed_in_for_long_retires_and_the_search_goes_on():
    from mission.team import MAX_HOLDS_IN_ROW

    brain = _searching_brain()
    ring = {u + 2: np.array([[2.0 + 1.2 * np.cos(a), 2.0 + 1.2 * np.sin(a), 1.5]])
            for u, a in enumerate(np.linspace(0, 2 * np.pi, 13))}
    for _ in range(MAX_HOLDS_IN_ROW):
        d = brain.replan(1, np.array([2.0, 2.0, 1.5, 0.0]), ring)
        assert d.hold_s > 0
    d = brain.replan(1, np.array([2.0, 2.0, 1.5, 0.0]), ring)
    assert d.retire and not d.done and d.outcome is Outcome.RETIRED and d.reason.startswith("search aborted")
    assert brain.final is None  # the team's search is not over


def test_search_dwells_are_attributed_to_the_vehicle_that_flew_them():
    """The joint brain counts every search dwell once and knows whose it was (a member's mission_summary.json
    gives its own count, the team's beside it): exploration dwells are neither."""
    scenario = load_scene("default").scenario()
    brain = TeamBrain(scenario, reproducible(SearchConfig()), TeamConfig(n_vehicles=2), seed=0)
    brain.add_dwell(0, np.array([1.0, 1.0, 1.5]), 10.0)  # exploring: not a search dwell
    assert brain.search_dwells == 0 and brain.search_dwelled_by == []
    brain.phase = Phase.SEARCH
    for v in (1, 0, 1):
        brain.add_dwell(v, np.array([2.0 + v, 1.0, 1.5]), 10.0)
    assert brain.search_dwells == 3 and brain.search_dwelled_by == [1, 0, 1]
    assert brain.dwelled_by == [0, 1, 0, 1]
