"""The joint estimate of a team (issue 18): each vehicle's odometry drift is a random walk of its own.

``PoseGroups`` must not chain vehicle A's last pose group to vehicle B's first; one vehicle's frames must be
grouped exactly as before.
"""

from __future__ import annotations

import numpy as np
import pytest

from detector_fw_sim.scene import load_scene
from estimator.mle import _MIN_INCREMENT, PoseGroups, walk_starts
from launch.offline import fly_offline
from mission.team import split_walks, team_dwell, team_frames
from tests.support.once_per_run import once_per_run


@pytest.fixture(scope="module")
def two_flights(tmp_path_factory):
    """Seeds 4 and 5 flown offline, once per run (both xdist workers use them)."""
    def fly(_folder):
        scene = load_scene("default")
        return [fly_offline(scene, seed=s).dataset.frames for s in (4, 5)]

    return once_per_run(tmp_path_factory, "team-estimate-two-flights", fly)


def _dense_precision(groups: PoseGroups) -> np.ndarray:
    g = groups.n_groups
    out = np.zeros((g, g))
    for i in range(g):
        e = np.zeros((g, 3))
        e[i, 0] = 1.0
        out[:, i] = groups.prior_times(e)[:, 0]
    return out


def test_one_vehicle_is_one_walk_as_before(two_flights):
    f = two_flights[0]
    assert walk_starts(f).sum() == 1
    groups = PoseGroups.from_frames(f)
    assert groups.kind == "random_walk" and groups.restarts is None
    mean_var = np.array([np.bincount(groups.index, weights=v) / np.bincount(groups.index)
                         for v in (f.var_x, f.var_y, f.var_z)]).T
    inc = np.maximum(np.diff(mean_var, axis=0, prepend=0.0), _MIN_INCREMENT)
    np.testing.assert_allclose(groups.variance, np.cumsum(inc, axis=0))  # the single-walk prior, unchanged


def test_two_vehicles_are_two_independent_walks(two_flights):
    a, b = two_flights
    joint = team_frames([a, b])
    assert walk_starts(joint).sum() == 2
    if a.t[-1] < b.t[-1]:  # team_frames puts the longer flight first (so that the next one starts earlier)
        a, b = b, a
    ga, gb = PoseGroups.from_frames(a), PoseGroups.from_frames(b)
    g = PoseGroups.from_frames(joint)
    assert g.n_groups == ga.n_groups + gb.n_groups
    assert np.flatnonzero(g.restarts).tolist() == [0, ga.n_groups]
    cov = np.linalg.inv(_dense_precision(g))
    # each walk's prior is that vehicle's alone: marginal variances as flown alone, no cross-covariance
    np.testing.assert_allclose(np.diag(cov), np.r_[ga.variance[:, 0], gb.variance[:, 0]], rtol=1e-9)
    np.testing.assert_allclose(cov[:ga.n_groups, ga.n_groups:], 0.0, atol=1e-15)
    # the banded solve agrees with the dense prior
    rhs = np.random.default_rng(0).normal(size=(g.n_groups, 3))
    x = g.solve(np.zeros((g.n_groups, 3, 3)), rhs)
    np.testing.assert_allclose(_dense_precision(g) @ x[:, 0], rhs[:, 0], rtol=1e-8)


def test_team_frames_keep_dwells_apart_and_split_back(two_flights):
    a, b = two_flights
    joint = team_frames([a, b])
    np.testing.assert_array_equal(joint.dwell[:len(a)] if a.t[-1] >= b.t[-1] else joint.dwell[len(b):],
                                  team_dwell(a.dwell, 0, 2))
    own = {int(d) % 2 for d in joint.dwell[joint.dwell >= 0]}
    assert own == {0, 1}
    walks = split_walks(joint)
    assert sorted(len(w) for w in walks) == sorted([len(a), len(b)])
    # a vehicle that flew for less time than the next one is moved first, so its walk still splits off
    short = a.select(np.arange(len(a)) < 40)
    assert walk_starts(team_frames([short, b])).sum() == 2
