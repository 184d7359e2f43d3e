"""Occupancy validity, the OMPL tree and the next-best-dwell-point planner: constraints that must hold."""

import math

import numpy as np
import pytest

from planner.belief import DwellHistory, SourceBelief
from planner.dwell_tree import TreeConfig, grow_tree, seed_ompl, shortcut_path
from planner.next_best import NextBestConfig, plan_next_dwell, score_nodes
from planner.occupancy import OccupancyMap
from planner.yaw_sampling import bearing_score, sample_yaw
from radseek.dataset import Wall
from radseek.topics import Plan

# a 10 x 8 m room: a long wall with a 1.2 m door between (5, 3.4) and (5, 4.6), and a short oblique wall
WALLS = (
    Wall((5.0, 0.0), (5.0, 3.4), 0.2, 3.0),
    Wall((5.0, 4.6), (5.0, 8.0), 0.2, 3.0),
    Wall((1.5, 5.0), (3.0, 6.5), 0.3, 2.0),
)
OCC = OccupancyMap(np.array([0.0, 0.0, 0.5]), np.array([10.0, 8.0, 2.5]), WALLS, radius=0.3)


def wall_clearance(points: np.ndarray, walls=WALLS) -> np.ndarray:
    """Distance (m) from points (n, 3) to the nearest un-grown wall slab (0 inside)."""
    out = np.full(len(points), np.inf)
    for w in walls:
        s0, s1 = np.array(w.start), np.array(w.end)
        length = np.linalg.norm(s1 - s0)
        u = (s1 - s0) / length
        rel = points[:, :2] - s0
        s, n = rel @ u, rel @ np.array([-u[1], u[0]])
        ds = np.maximum(np.maximum(-s, s - length), 0)
        dn = np.maximum(np.abs(n) - w.thickness / 2, 0)
        dz = np.maximum(np.maximum(-points[:, 2], points[:, 2] - w.height), 0)
        out = np.minimum(out, np.sqrt(ds**2 + dn**2 + dz**2))
    return out


def test_scalar_and_vectorised_validity_agree():
    rng = np.random.default_rng(1)
    a = rng.uniform([-0.5, -0.5, 0.0], [10.5, 8.5, 3.5], (3000, 3))
    b = rng.uniform([-0.5, -0.5, 0.0], [10.5, 8.5, 3.5], (3000, 3))
    np.testing.assert_array_equal(OCC.points_valid(a), [OCC.point_valid(*p) for p in a])
    scalar = [OCC.segment_valid(p, q) for p, q in zip(a, b, strict=True)]
    np.testing.assert_array_equal(OCC.segments_valid(a, b), scalar)


def test_valid_segments_keep_the_vehicle_radius_clear_of_walls():
    rng = np.random.default_rng(2)
    a = rng.uniform(OCC.free_min, OCC.free_max, (2000, 3))
    b = a + rng.normal(0, 1.5, (2000, 3))
    ok = OCC.segments_valid(a, b)
    assert 100 < ok.sum() < len(ok)  # both outcomes are exercised
    t = np.linspace(0, 1, 201)[:, None, None]
    pts = (a[ok] + t * (b[ok] - a[ok])).reshape(-1, 3)
    assert wall_clearance(pts).min() >= OCC.radius - 1e-9


def test_a_segment_clipping_a_grown_corner_by_1_cm_is_invalid():
    occ = OccupancyMap(np.zeros(3), np.array([5.0, 5.0, 3.0]), (Wall((0.5, 2.0), (2.5, 2.0), 0.2, 3.0),), 0.3)
    # the grown wall spans x <= 2.8, y <= 2.4; this segment is inside it only for t in [0.483, 0.5]
    a, b = np.array([2.5, 2.69, 1.0]), np.array([3.1, 2.09, 1.0])
    assert not occ.segment_valid(a, b)
    assert not occ.segments_valid(a, b)
    # sampling at 5 cm would have missed it: no sample lies inside the grown wall
    pts = a + np.linspace(0, 1, int(np.linalg.norm(b - a) / 0.05) + 1)[:, None] * (b - a)
    assert occ.points_valid(pts).all()


def test_a_start_just_inside_the_clearance_moves_to_its_edge():
    # a wall along y = 2 (0.2 m thick, so its face at y = 2.1); grown by 0.3 m its clearance ends at y = 2.4
    occ = OccupancyMap(np.zeros(3), np.array([5.0, 5.0, 3.0]), (Wall((0.5, 2.0), (4.5, 2.0), 0.2, 3.0),), 0.3)
    inside = np.array([2.5, 2.35, 1.5])
    assert not occ.point_valid(*inside)
    free = occ.nearest_valid(inside, step=0.005)
    assert occ.point_valid(*free) and free[2] == 1.5
    # the edge is 0.05 m away: the first ring of candidates (0.005 m apart, 64 bearings) to clear it is within 0.06 m
    assert free[1] >= 2.4 and np.linalg.norm(free[:2] - inside[:2]) <= 0.06
    assert np.array_equal(occ.nearest_valid(free), free)  # a valid point stays
    assert occ.nearest_valid(np.array([2.5, 2.0, 1.5]), max_shift=0.2) is None  # deep inside: none near


def test_flying_over_a_low_wall_is_valid_but_not_through_it():
    occ = OccupancyMap(np.zeros(3), np.array([5.0, 5.0, 3.0]), (Wall((2.5, 0.0), (2.5, 5.0), 0.2, 1.0),), 0.3)
    assert occ.segment_valid((1.0, 2.5, 1.5), (4.0, 2.5, 1.5))  # 1.5 > 1.0 + 0.3
    assert not occ.segment_valid((1.0, 2.5, 1.2), (4.0, 2.5, 1.2))


@pytest.fixture(scope="module")
def tree():
    return grow_tree(np.array([1.0, 1.0, 1.5, 0.0]), OCC, TreeConfig(n_max=500, time_budget=5.0, time_limit=10.0))


def test_tree_size_root_and_structure(tree):
    assert len(tree) == 500
    np.testing.assert_allclose(tree.states[0], [1.0, 1.0, 1.5, 0.0])
    assert tree.parent[0] == -1 and np.all(tree.parent[1:] >= 0)
    for i in range(0, len(tree), 37):  # every node leads back to the root without cycles
        p = tree.path_to(i)
        assert len(p) <= len(tree)
        np.testing.assert_allclose(p[0], tree.states[0])
        np.testing.assert_allclose(p[-1], tree.states[i])


def test_tree_edges_are_short_collision_free_and_within_the_yaw_rate(tree):
    cfg = TreeConfig()
    a, b = tree.edges()
    length = np.linalg.norm(b[:, :3] - a[:, :3], axis=1)
    assert np.all(length <= cfg.max_edge + 1e-9)
    assert np.all(OCC.segments_valid(a[:, :3], b[:, :3]))
    assert np.all(OCC.points_valid(tree.states[:, :3]))
    dpsi = np.abs((b[:, 3] - a[:, 3] + np.pi) % (2 * np.pi) - np.pi)
    assert np.all(dpsi <= cfg.yaw_rate_max * length / cfg.speed + 1e-9)


def test_tree_crosses_the_wall_only_through_the_door(tree):
    a, b = tree.edges()
    crossing = (a[:, 0] - 5.0) * (b[:, 0] - 5.0) < 0
    assert crossing.any()  # it did explore beyond the wall
    t = (5.0 - a[crossing, 0]) / (b[crossing, 0] - a[crossing, 0])
    y = a[crossing, 1] + t * (b[crossing, 1] - a[crossing, 1])
    assert np.all((y >= 3.4 + OCC.radius - 1e-9) & (y <= 4.6 - OCC.radius + 1e-9))  # grown wall ends


def test_reseeding_ompl_repeats_the_tree_whatever_was_grown_before():
    # a node-count-bounded tree depends on OMPL's random generators only: after seed_ompl(s) the same tree
    # grows again even though other trees (other generators) were grown in between; another seed differs
    cfg = TreeConfig(n_min=60, n_max=60, time_budget=60.0, time_limit=60.0)
    start = np.array([1.0, 1.0, 1.5, 0.0])
    seed_ompl(21)
    first = grow_tree(start, OCC, cfg)
    grow_tree(start, OCC, cfg)
    seed_ompl(21)
    again = grow_tree(start, OCC, cfg)
    seed_ompl(22)
    other = grow_tree(start, OCC, cfg)
    assert len(first) == len(again) == 60
    np.testing.assert_array_equal(first.states, again.states)
    np.testing.assert_array_equal(first.parent, again.parent)
    assert len(other) != len(first) or not np.array_equal(other.states, first.states)


def test_start_inside_a_wall_is_refused():
    with pytest.raises(ValueError):
        grow_tree(np.array([5.0, 1.0, 1.5, 0.0]), OCC)


def test_semi_major_axis_rejection_uses_the_largest_eigenvalue():
    belief = SourceBelief(np.array([7.0, 4.0, 0.0]), np.diag([4.0, 0.01, 0.01]), 1000.0, 10.0)
    nodes = np.array([[7.0, 4.0 + 1.5, 0.0], [7.0, 4.0 + 2.5, 0.0], [7.0 + 1.9, 4.0, 0.0]])
    s = score_nodes(nodes, belief, DwellHistory(), OCC, NextBestConfig(lambda_min_cps=0.0), root=None)
    # semi-major axis sqrt(4) = 2 m: 1.5 m across the ellipse is rejected although it is 15 sigma in y
    np.testing.assert_array_equal(s.too_close, [True, False, True])
    # adding the pose covariance grows the axis: sqrt(4 + 2.5) = 2.55 m also rejects the 2.5 m node
    s2 = score_nodes(nodes, belief, DwellHistory(), OCC, NextBestConfig(lambda_min_cps=0.0),
                     pose_covariance=np.eye(3) * 2.5, root=None)
    assert s2.too_close.all()


def test_lambda_min_rejects_weak_and_shielded_nodes():
    belief = SourceBelief(np.array([7.0, 2.0, 0.0]), np.eye(3) * 0.01, 100.0, 10.0)
    nodes = np.array([[7.0, 6.0, 1.5], [3.0, 2.0, 1.5], [7.0, 3.0, 1.5]])  # 4.3 m, 4.3 m behind the wall, 1.8 m
    # 100 / 4.27^2 = 5.5 cps: kept at lambda_min = 5, dropped at 6
    s = score_nodes(nodes, belief, DwellHistory(), OCC, NextBestConfig(lambda_min_cps=5.0), root=None)
    np.testing.assert_array_equal(s.too_weak, [False, False, False])
    s = score_nodes(nodes, belief, DwellHistory(), OCC, NextBestConfig(lambda_min_cps=6.0), root=None)
    np.testing.assert_array_equal(s.too_weak, [True, True, False])
    # with a wall attenuation of 3 /m the node behind the 0.2 m wall drops to ~5.5 * e^-0.6 (still about 0.2
    # m of path): rejected at lambda_min = 5 while the unshielded one is kept
    s = score_nodes(nodes, belief, DwellHistory(), OCC, NextBestConfig(lambda_min_cps=5.0, wall_mu_per_m=3.0),
                    root=None)
    np.testing.assert_array_equal(s.too_weak, [False, True, False])


@pytest.fixture(scope="module")
def planned(tree):
    belief = SourceBelief(np.array([7.5, 4.0, 0.0]), np.eye(3) * 0.09, 2000.0, 30.0)
    history = DwellHistory(np.array([[1.0, 1.0, 1.5], [3.0, 2.0, 1.5], [4.0, 4.0, 1.5]]), np.array([60, 90, 200.0]))
    cfg = NextBestConfig()
    plan = plan_next_dwell(tree.states[0], belief, history, OCC, cfg, rng=np.random.default_rng(0), tree=tree)
    return plan, belief, history, cfg, tree


def test_next_best_is_the_best_valid_node_and_obeys_the_constraints(planned):
    plan, belief, history, cfg, tree = planned
    assert plan.ok and len(plan.dwell_points) == 1
    s = score_nodes(tree.states[:, :3], belief, history, OCC, cfg)
    best = plan.info["best_node"]
    assert s.valid[best] and s.gain[best] == pytest.approx(s.gain[s.valid].max())
    p = plan.dwell_points[0, :3]
    np.testing.assert_allclose(p, tree.states[best, :3])
    assert np.linalg.norm(p - belief.mean) >= belief.semi_major_axis()
    assert belief.predicted_net_rate(p) >= cfg.lambda_min_cps


def test_planned_path_is_collision_free_and_flyable(planned):
    plan, belief, _, cfg, tree = planned
    path = plan.path
    np.testing.assert_allclose(path[0], tree.states[0])
    np.testing.assert_allclose(path[-1], plan.dwell_points[0])
    assert np.all(OCC.segments_valid(path[:-1, :3], path[1:, :3]))
    ds = np.linalg.norm(np.diff(path[:, :3], axis=0), axis=1)
    dpsi = np.abs((np.diff(path[:, 3]) + np.pi) % (2 * np.pi) - np.pi)
    assert np.all(dpsi <= cfg.tree.yaw_rate_max * ds / cfg.tree.speed + 1e-9)
    # the source is behind the door: the path went through it
    assert path[:, 0].max() > 5.0


def test_plan_converts_to_the_topic_payload(planned):
    plan = planned[0]
    msg = Plan.from_bytes(plan.to_topic(12.5).to_bytes())
    assert msg.t == 12.5
    np.testing.assert_allclose(msg.points("dwell_points"), plan.dwell_points)  # (x, y, z, yaw) per point
    np.testing.assert_allclose(msg.points("path"), plan.path)


def test_no_valid_node_gives_an_empty_plan(tree):
    belief = SourceBelief(np.array([7.5, 4.0, 0.0]), np.eye(3) * 100.0, 2000.0, 30.0)  # 10 m semi-major axis
    plan = plan_next_dwell(tree.states[0], belief, DwellHistory(), OCC, tree=tree)
    assert not plan.ok and plan.info["valid_nodes"] == 0


def test_shortcut_keeps_the_path_valid_and_never_longer(tree):
    for i in range(1, len(tree), 50):
        raw = tree.path_to(i)
        short = shortcut_path(raw, OCC)
        assert np.all(OCC.segments_valid(short[:-1], short[1:]))
        assert np.linalg.norm(np.diff(short, axis=0), axis=1).sum() <= \
            np.linalg.norm(np.diff(raw[:, :3], axis=0), axis=1).sum() + 1e-9


def test_yaw_sequence_respects_the_rate_limit_and_faces_the_source_when_it_can():
    rng = np.random.default_rng(4)
    src = np.array([0.0, 5.0, 0.0])
    pts = np.c_[np.linspace(0, 4, 12), np.zeros(12), np.full(12, 1.5)]
    for rate in (0.05, 0.5, 5.0):
        yaw = sample_yaw(pts, 0.0, bearing_score(src), q=8, speed=0.5, yaw_rate_max=rate, rng=rng,
                         extra=np.arctan2(src[1] - pts[:, 1], src[0] - pts[:, 0])[:, None])
        assert yaw[0] == 0.0
        dpsi = np.abs((np.diff(yaw) + np.pi) % (2 * np.pi) - np.pi)
        assert np.all(dpsi <= rate * np.linalg.norm(np.diff(pts, axis=0), axis=1) / 0.5 + 1e-9)
    # with a fast yaw the final heading is the bearing to the source (a deterministic candidate)
    assert yaw[-1] == pytest.approx(math.atan2(5.0, -4.0))


def test_belief_from_an_estimate_message():
    from radseek.topics import Estimate, PayloadError

    full = np.diag([0.04, 0.09, 0.01, 400.0])
    full[0, 1] = full[1, 0] = 0.02
    msg = Estimate(t=3.0, method="pf", sources=[{"x": 1.0, "y": 2.0, "z": 0.0, "cps_at_1m": 900.0}],
                   background_cps=25.0, covariance=full.ravel().tolist())
    b = SourceBelief.from_estimate(msg)
    np.testing.assert_allclose(b.mean, [1.0, 2.0, 0.0])
    np.testing.assert_allclose(b.covariance, full[:3, :3])
    assert b.cps_at_1m == 900.0 and b.background_cps == 25.0
    # no silent fallback: a covariance in another layout (here the whole 4 x 4 as rows) is refused
    with pytest.raises(PayloadError, match="covariance"):
        SourceBelief.from_estimate(Estimate(t=0.0, method="x", sources=msg.sources, background_cps=25.0,
                                            covariance=full.tolist()))
