"""Baselines (lattice, lawnmower, spiral, PRE Algorithm 1, greedy info gain) and frontier exploration."""

import math

import numpy as np
import pytest

from planner import baselines as bl
from planner.belief import DwellHistory, SourceBelief
from planner.dwell_tree import TreeConfig
from planner.exploration import (
    FrontierConfig,
    exploration_done,
    frontier_cells,
    frontier_cost,
    intensity_gradient,
    plan_exploration,
    visited_cells,
)
from planner.occupancy import OccupancyMap
from radseek.dataset import Wall

OPEN = OccupancyMap(np.array([-10.0, -10.0, 0.5]), np.array([10.0, 10.0, 2.5]), (), radius=0.3)


def test_fixed_lattice_is_nine_points_on_a_grid_in_boustrophedon_order():
    pts = bl.fixed_lattice(np.array([5.0, 4.0, 1.5]), spacing=1.5)
    assert pts.shape == (9, 3)
    assert len({tuple(p) for p in pts}) == 9
    np.testing.assert_allclose(pts.mean(0), [5.0, 4.0, 1.5])
    np.testing.assert_allclose(np.linalg.norm(np.diff(pts, axis=0), axis=1), 1.5)  # neighbours only


def test_lawnmower_covers_the_area_in_lanes_within_bounds():
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([6.0, 4.0, 3.0])
    pts = bl.lawnmower(lo, hi, spacing=1.0, z=1.5, margin=0.5)
    assert pts.shape == (6 * 4, 3)
    assert np.all((pts[:, :2] >= 0.5) & (pts[:, :2] <= hi[:2] - 0.5))
    steps = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    np.testing.assert_allclose(steps, 1.0)  # boustrophedon: lane ends join by one step


def test_spiral_points_are_evenly_spaced_and_move_outwards():
    c = np.array([0.0, 0.0, 1.5])
    pts = bl.spiral(c, 0.8, np.array([-5.0, -5.0]), np.array([5.0, 5.0]))
    r = np.linalg.norm(pts[:, :2], axis=1)
    inner = pts[1:][r[1:] < 5.0]  # turns not yet clipped by the square bounds (later ones keep only corners)
    steps = np.linalg.norm(np.diff(inner, axis=0), axis=1)
    assert len(inner) > 20 and np.all(np.abs(steps - 0.8) < 0.1 * 0.8)  # chord of an arc of 0.8 m
    assert np.all(np.diff(r) > 0)
    assert np.all(np.abs(pts[:, :2]) <= 5.0)
    assert r.max() > 4.0  # it reached the bounds before stopping


def test_pre_step_follows_algorithm_1_by_hand():
    policy = bl.PREGradient(threshold=100.0, step=1.0, q=1e-3)  # tiny q: softmax is an argmax
    rng = np.random.default_rng(0)
    nbrs = np.array([50.0, 40, 30, 20, 10, 10, 10, 10])  # up (+y) rises fastest
    nxt = policy.step_from(np.zeros(3), 20.0, nbrs, rng)
    np.testing.assert_allclose(nxt, [0.0, 1.0, 0.0])
    assert policy.rid_flag  # 20 < E: still approaching
    policy.step_from(nxt, 150.0, nbrs, rng)  # reading above E flips RID FLAG (line 7-8)
    assert not policy.rid_flag
    # circling: above E move along e2, clockwise of e1 = (0, 1) -> (1, 0); below E along e1
    np.testing.assert_allclose(policy.step_from(np.zeros(3), 150.0, nbrs, rng), [1.0, 0.0, 0.0])
    np.testing.assert_allclose(policy.step_from(np.zeros(3), 50.0, nbrs, rng), [0.0, 1.0, 0.0])


def test_pre_softmax_probabilities_match_eq_1():
    # gradients (0, 1, 0, ...) with q = 1: P(direction 1) = e / (e + 7); check by frequency over 4000 draws,
    # binomial sd sqrt(p (1 - p) / 4000) ~ 0.0077, bound 4 sd
    p = math.e / (math.e + 7)
    rng = np.random.default_rng(1)
    hits = 0
    for _ in range(4000):
        policy = bl.PREGradient(threshold=1e9, step=1.0, q=1.0)
        nxt = policy.step_from(np.zeros(3), 0.0, np.array([0.0, 1, 0, 0, 0, 0, 0, 0]), rng)
        hits += np.allclose(nxt[:2], bl.UNIT_DIRECTIONS[1])
    assert abs(hits / 4000 - p) < 4 * math.sqrt(p * (1 - p) / 4000)


def test_pre_rollout_reaches_the_threshold_region_and_stops_on_a_closed_loop():
    src = np.array([3.0, 2.0, 0.0])

    def rate_at(p):  # a rate callback, as the benchmark hook would give (here inverse square + 10 cps)
        return 1000 / np.maximum(((p - src) ** 2).sum(-1), 0.01) + 10

    policy = bl.PREGradient(threshold=150.0, step=0.5, q=0.5)
    pts = bl.run_pre(np.array([-3.0, -3.0, 1.5]), rate_at, policy, np.random.default_rng(0), OPEN, max_points=80)
    assert not policy.rid_flag and len(pts) < 80 and bl.path_closed(pts)
    # E = 150 cps is reached within sqrt(1000 / 140 - 1.5^2) = 2.2 m of the source (horizontal)
    assert np.linalg.norm(pts[:, :2] - src[:2], axis=1).min() < 2.2 + 0.5


def test_path_closed_detects_a_crossing():
    square = np.array([[0, 0], [1, 0], [1, 1], [0.5, 1], [0.5, -0.5]], dtype=float)
    assert bl.path_closed(square)
    assert not bl.path_closed(np.array([[0, 0], [1, 0], [2, 0.5], [3, 1.5]], dtype=float))


def test_particle_entropy_by_hand():
    assert bl.particle_entropy(np.ones(4)) == pytest.approx(math.log(4))
    assert bl.particle_entropy(np.array([1.0, 0, 0])) == pytest.approx(0.0)


def test_greedy_info_gain_moves_towards_the_belief_and_avoids_walls():
    belief = SourceBelief(np.zeros(3), np.eye(3), 1000.0, 10.0)
    best, u = bl.greedy_info_gain(np.array([5.0, 0.0, 1.5]), belief, OPEN, rng=np.random.default_rng(0))
    assert best[0] < 5.0  # a measurement nearer the cloud discriminates particles better
    walled = OccupancyMap(OPEN.bounds_min, OPEN.bounds_max, (Wall((4.5, -3), (4.5, 3), 0.2, 3.0),), 0.3)
    best, u = bl.greedy_info_gain(np.array([5.0, 0.0, 1.5]), belief, walled, rng=np.random.default_rng(0))
    assert best[0] > 5.0 - 1e-9 and np.isinf(u[5:]).all()  # the three moves west are blocked


def test_frontier_cells_and_costs_by_hand():
    occupied = np.zeros((5, 5), dtype=bool)
    occupied[2, 3] = True
    visited = np.zeros((5, 5), dtype=bool)
    visited[2, 2] = True
    f = frontier_cells(occupied, visited)
    expected = np.zeros((5, 5), dtype=bool)
    expected[1:4, 1:4] = True
    expected[2, 2] = expected[2, 3] = False
    np.testing.assert_array_equal(f, expected)
    cells = np.array([[2.0, 0.0], [-2.0, 0.0], [0.0, 2.0]])
    np.testing.assert_allclose(frontier_cost(cells, np.zeros(2), None, 0.8), 0.8 * 2)
    # gradient +x: ahead on the line costs alpha d, behind costs d, aside alpha d + (1 - alpha) d (eq. 4.1-4.2)
    np.testing.assert_allclose(frontier_cost(cells, np.zeros(2), np.array([1.0, 0.0]), 0.8), [1.6, 2.0, 2.0])


def test_intensity_gradient_recovers_a_plane_and_needs_three_points():
    pos = np.array([[0, 0, 1], [2, 0, 1], [0, 3, 1], [1, 1, 1.0]])
    rates = 10 + 2 * pos[:, 0] - 1 * pos[:, 1]
    np.testing.assert_allclose(intensity_gradient(DwellHistory(pos, rates)), [2.0, -1.0], atol=1e-9)
    assert intensity_gradient(DwellHistory(pos[:2], rates[:2])) is None
    collinear = np.array([[0, 0, 1], [1, 1, 1], [2, 2, 1.0]])
    assert intensity_gradient(DwellHistory(collinear, np.array([1.0, 2, 3]))) is None


def test_exploration_ends_after_three_readings_above_background():
    b = 30.0  # 3 sigma over 5 s: sqrt(30 / 5) * 3 = 7.3 cps above background
    pos = np.zeros((4, 3))
    assert not exploration_done(DwellHistory(pos, np.array([31.0, 40, 45, 36])), b)
    assert exploration_done(DwellHistory(pos, np.array([31.0, 40, 45, 38])), b)


def test_visited_cells_by_radius():
    xs = ys = np.arange(5.0)
    v = visited_cells(xs, ys, np.array([[2.0, 2.0, 1.5]]), 1.0)
    assert v.sum() == 5 and v[2, 2]


def test_exploration_plan_reaches_a_frontier_without_crossing_walls():
    occ = OccupancyMap(np.array([0.0, 0.0, 0.5]), np.array([8.0, 6.0, 2.5]), (Wall((3.0, 0), (3.0, 4.5), 0.2, 3),), 0.3)
    cfg = FrontierConfig()
    plan = plan_exploration(np.array([1.0, 1.0, 1.5, 0.0]), DwellHistory(), occ, config=cfg,
                            rng=np.random.default_rng(0))
    assert plan.ok
    assert np.all(occ.segments_valid(plan.path[:-1, :3], plan.path[1:, :3]))
    target = np.array(plan.info["frontier"])
    assert np.linalg.norm(plan.dwell_points[0, :2] - target) <= cfg.resolution + 1e-9
    # the chosen frontier is just outside the sensed disc around the start
    assert cfg.sensing_radius - cfg.resolution <= np.linalg.norm(target - [1.0, 1.0]) <= cfg.sensing_radius + 1.0


def test_exploration_flies_straight_to_a_frontier_the_tree_missed():
    # a tree of 2 nodes (what a time-budgeted tree can shrink to on a loaded machine is 100 in 625 m^2) reaches
    # no frontier cell of a 25 m field from its corner; a free straight segment to one still gives a plan
    occ = OccupancyMap(np.array([0.0, 0.0, 0.0]), np.array([25.0, 25.0, 2.5]), (), 0.3)
    cfg = FrontierConfig(tree=TreeConfig(n_min=2, n_max=2))
    start = np.array([0.3, 0.3, 1.5, 0.0])
    plan = plan_exploration(start, DwellHistory(), occ, config=cfg, rng=np.random.default_rng(0))
    assert plan.info["reachable"] == 0 and plan.info["straight"] > 0
    assert plan.ok
    assert np.all(occ.segments_valid(plan.path[:-1, :3], plan.path[1:, :3]))
    target = np.array(plan.info["frontier"])
    np.testing.assert_allclose(plan.dwell_points[0, :2], target)
    assert cfg.sensing_radius <= np.linalg.norm(target - start[:2]) <= cfg.sensing_radius + 1.0
    # behind a wall that blocks every straight line the plan is still empty, never through the wall
    wall = Wall((2.5, 0.0), (2.5, 2.5), 0.2, 3.0), Wall((0.0, 2.5), (2.5, 2.5), 0.2, 3.0)
    boxed = OccupancyMap(np.array([0.0, 0.0, 0.0]), np.array([25.0, 25.0, 2.5]), wall, 0.3)
    plan = plan_exploration(np.array([1.0, 1.0, 1.5, 0.0]), DwellHistory(), boxed, config=cfg,
                            rng=np.random.default_rng(0))
    assert not plan.ok or np.all(boxed.segments_valid(plan.path[:-1, :3], plan.path[1:, :3]))


def test_exploration_returns_an_empty_plan_when_everything_is_visited():
    plan = plan_exploration(np.array([1.0, 1.0, 1.5, 0.0]), DwellHistory(), OPEN,
                            config=FrontierConfig(sensing_radius=100.0))
    assert not plan.ok and plan.info["frontier_cells"] == 0
