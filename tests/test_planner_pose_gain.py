"""Eq. 6 under pose covariance (issue 13 item 3): analytic cases of the gain, the drift density from
recorded poses, tree path lengths, and a seeded statistical comparison of metres flown."""

import dataclasses

import numpy as np
import pytest

from planner.belief import DwellHistory, SourceBelief, drift_density_from_poses
from planner.dwell_tree import Tree
from planner.gain import GainConfig, gain_eq6, gain_eq6_pose, pose_information_factor, rate_gradient
from planner.next_best import NextBestConfig, score_nodes
from planner.occupancy import OccupancyMap

SRC = np.array([5.0, 4.0, 0.0])
A, B = 1600.0, 30.0
DENSITY = np.array([9e-4, 9e-4, 1e-4])  # the mock vehicle's odometry: 0.03 m/sqrt(m) in x, y; 0.01 in z


def test_zero_density_gives_eq6_exactly():
    rng = np.random.default_rng(0)
    nodes = rng.uniform([0, 0, 1], [10, 8, 2], (300, 3))
    dwells = rng.uniform([0, 0, 1.5], [10, 8, 1.5], (4, 3))
    length = rng.uniform(0, 20, 300)
    cov = np.diag([0.04, 0.02, 0.0])
    g = gain_eq6_pose(nodes, SRC, dwells, length, cov, A, B, 0.0, GainConfig())
    np.testing.assert_array_equal(g, gain_eq6(nodes, SRC, dwells, GainConfig()))
    # and with drift but nothing flown
    g0 = gain_eq6_pose(nodes, SRC, dwells, np.zeros(300), cov, A, B, DENSITY, GainConfig())
    np.testing.assert_allclose(g0, gain_eq6(nodes, SRC, dwells, GainConfig()), rtol=1e-12)


def test_factor_matches_the_hand_computed_kalman_reduction():
    """One node straight east of the source at 1 m horizontal, 1.5 m up; isotropic horizontal belief."""
    node = np.array([[6.0, 4.0, 1.5]])
    r2 = 1.0 + 2.25
    g = 2 * A * np.array([1.0, 0.0, 1.5]) / r2**2  # paper 004 eq. 5.5-5.6 in 3-D
    np.testing.assert_allclose(rate_gradient(node, SRC, A)[0], g)
    cov = np.diag([0.01, 0.01, 0.0])
    s2 = (A / r2 + B) / 10.0
    L = 3.0
    sp = L * DENSITY

    def reduction(extra):
        su_g = (np.diag(cov) + extra) * g
        return su_g @ su_g / (s2 + su_g @ g) - extra.sum()

    expected = reduction(sp) / reduction(np.zeros(3))
    k = pose_information_factor(node, [L], SRC, cov, A, B, DENSITY, dwell_s=10.0)
    assert k[0] == pytest.approx(expected, rel=1e-12)
    assert 0 < k[0] < 1


def test_factor_is_one_at_zero_path_and_falls_with_path_length_and_density():
    node = np.array([[6.5, 4.0, 1.5]])
    cov = np.diag([0.02, 0.02, 0.0])
    lengths = np.linspace(0, 30, 61)
    k = pose_information_factor(np.repeat(node, len(lengths), 0), lengths, SRC, cov, A, B, DENSITY)
    assert k[0] == 1.0
    assert np.all(np.diff(k) <= 1e-15) and k[-1] < k[1] < 1
    ks = [pose_information_factor(node, [4.0], SRC, cov, A, B, d * DENSITY)[0] for d in (0, 0.5, 1, 2, 4)]
    assert ks[0] == 1.0 and np.all(np.diff(ks) < 0)
    # a tight belief loses more to the same drift than a broad one: metres cost most late in the search
    broad = pose_information_factor(node, [4.0], SRC, np.diag([0.25, 0.25, 0.0]), A, B, DENSITY)[0]
    assert broad > ks[2]


def test_far_candidate_loses_against_a_near_one_of_equal_eq6_gain_as_density_grows():
    """Two nodes symmetric about the source (equal eq. 6 gain and equal information), one reached after
    1 m, the other after 6 m: equal gain without drift; with drift the near one wins, by more as the
    density grows."""
    nodes = np.array([[6.0, 4.0, 1.5], [4.0, 4.0, 1.5]])
    dwells = np.array([[5.0, 1.0, 1.5]])  # on the symmetry axis: equal repulsion
    cov = np.diag([0.01, 0.01, 0.0])
    lengths = np.array([1.0, 6.0])
    g0 = gain_eq6_pose(nodes, SRC, dwells, lengths, cov, A, B, 0.0)
    assert g0[0] == pytest.approx(g0[1], rel=1e-12)
    margins = []
    for scale in (0.25, 1.0, 4.0):
        g = gain_eq6_pose(nodes, SRC, dwells, lengths, cov, A, B, scale * DENSITY)
        assert g[0] > g[1]
        margins.append(g[0] / max(g[1], 1e-300))
    assert np.all(np.diff(margins) > 0)


def test_score_nodes_switches_the_best_node_only_with_the_pose_gain():
    occ = OccupancyMap(np.array([0.0, 0.0, 0.5]), np.array([10.0, 8.0, 2.5]), (), 0.3)
    belief = SourceBelief(SRC, np.diag([0.01, 0.01, 0.0]), A, B, drift_density=DENSITY)
    # the far node has a slightly larger eq. 6 gain (a little nearer the source, both ~1 m off; r > delta)
    pos = np.array([[5.0, 5.0, 1.5], [6.0, 4.0, 1.5], [4.05, 4.0, 1.5]])
    history = DwellHistory(np.array([[5.0, 1.0, 1.5]]), np.array([200.0]))
    length = np.array([0.0, 0.8, 7.0])
    cfg = NextBestConfig(lambda_min_cps=0.0, ellipsoid_sigma=0.0)
    old = score_nodes(pos, belief, history, occ, cfg, path_length=length)
    new = score_nodes(pos, belief, history, occ, dataclasses.replace(cfg, gain_kind="eq6_pose"), path_length=length)
    assert old.best == 2 and new.best == 1
    # with the density zeroed the pose gain is eq. 6 again
    flat = dataclasses.replace(belief, drift_density=0.0)
    same = score_nodes(pos, flat, history, occ, dataclasses.replace(cfg, gain_kind="eq6_pose"), path_length=length)
    np.testing.assert_array_equal(same.gain, old.gain)


def test_config_rejects_an_unknown_gain():
    with pytest.raises(ValueError):
        NextBestConfig(gain_kind="entropy")
    with pytest.raises(ValueError):
        SourceBelief(SRC, np.eye(3), A, B, drift_density=-1.0)


def test_drift_density_from_recorded_poses():
    # 0.0009 m^2 per metre along a 5 m leg, a hover (jitter, no growth) and a 3 m leg
    leg1 = np.c_[np.linspace(0, 5, 51), np.zeros(51), np.full(51, 1.5)]
    hover = leg1[-1] + np.random.default_rng(1).normal(0, 0.01, (30, 3))
    leg2 = np.c_[np.full(31, 5.0), np.linspace(0, 3, 31), np.full(31, 1.5)]
    pos = np.vstack([leg1, hover, leg2])
    flown = np.r_[np.linspace(0, 5, 51), np.full(30, 5.0), 5 + np.linspace(0, 3, 31)]
    var = 1e-4 + flown[:, None] * DENSITY
    dwell = np.r_[np.full(51, -1), np.zeros(30, int), np.full(31, -1)]
    got = drift_density_from_poses(pos, var, dwell)
    np.testing.assert_allclose(got, DENSITY, rtol=0.02)
    assert np.all(drift_density_from_poses(pos[:1], var[:1]) == 0)
    assert np.all(drift_density_from_poses(pos, np.full_like(var, 1e-4)) == 0)  # no growth: exact poses


def test_tree_path_lengths_follow_the_parents():
    states = np.array([[0, 0, 1, 0], [1, 0, 1, 0], [1, 2, 1, 0], [0, 0, 2, 0], [1, 2, 4, 0.0]])
    parent = np.array([-1, 0, 1, 0, 2])
    t = Tree(states, parent, 0.0, 0)
    np.testing.assert_allclose(t.path_lengths(), [0, 1, 3, 1, 6])
    for i in range(len(t)):
        p = t.path_to(i)[:, :3]
        assert t.path_lengths()[i] == pytest.approx(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


@pytest.mark.slow
def test_pose_gain_commits_to_no_more_metres_than_eq6_on_the_same_trees():
    """Seeded whole searches (launch.offline, default scene, real drift): at every next-best decision both
    gains score the same tree, so the paired difference of the chosen node's path length isolates the gain
    (OMPL's trees are not seedable per call; a tree with no valid node, which either gain
leaves unchosen, drops out). Its mean over the decisions of a few seeds must not exceed
    zero by more than its spread allows (3 standard errors, plus 5 cm for the case where every pair is
    equal and the spread is zero)."""
    from benchmarks.planner_pose_gain import same_tree_choices

    rows = [r for seed in range(5) for r in same_tree_choices("default", seed)]
    pose = np.array([r["L_eq6_pose"] for r in rows])
    eq6 = np.array([r["L_eq6"] for r in rows])
    # a tree may hold no valid node (all too close or too weak: NaN); validity does not depend on the gain
    np.testing.assert_array_equal(np.isnan(pose), np.isnan(eq6))
    d = (pose - eq6)[np.isfinite(eq6)]
    assert len(d) >= 5
    se = d.std(ddof=1) / np.sqrt(len(d))
    assert d.mean() <= 3 * se + 0.05, (d.mean(), se)
