"""A team flown in-process (issue 18): the joint brain with N emulated vehicles on one sim clock."""

from __future__ import annotations

import math

import pytest
from scipy import stats

from detector_fw_sim.scene import load_scene
from launch.campaign import coverage
from launch.offline_team import fly_team_offline
from mission.team import TeamConfig

SCENE = load_scene("default")


def test_two_vehicles_find_the_source_apart():
    r = fly_team_offline(SCENE, 2, seed=0)
    assert r.brain.final is not None and r.brain.final.outcome.found, r.log
    assert r.error_m < 0.3
    assert all(p["dwell_points"] >= 1 and p["distance_m"] > 0 for p in r.per_vehicle)
    assert sum(p["dwell_points"] for p in r.per_vehicle) == len(r.brain.history)
    # the allocation holds the separation on the poses the vehicles fly on (their estimates) ...
    assert r.min_separation_est_m >= TeamConfig().separation_m - 1e-9
    # ... and the truth differs from them by the two vehicles' independent drifts: after d metres each drift is
    # N(0, 0.03^2 d) per axis; 5 sigma of the x-y difference of two 10 m walks is 5 * 0.03 * sqrt(2 * 2 * 10)
    assert r.min_separation_m >= TeamConfig().separation_m - 5 * 0.03 * math.sqrt(40)
    # the team's frames hold both vehicles' walks
    assert {int(d) % 2 for d in r.dataset.frames.dwell if d >= 0} == {0, 1}


def test_the_others_finish_when_one_vehicle_fails():
    r = fly_team_offline(SCENE, 2, seed=1, fail={1: 12.0})
    assert r.per_vehicle[1]["failed_at"] == 12.0
    assert r.brain.final is not None and r.brain.final.outcome.found, r.log
    assert r.brain.dwelled_by[-1] == 0  # vehicle 0 ended the search
    assert r.per_vehicle[0]["dwell_points"] > r.per_vehicle[1]["dwell_points"]
    assert r.error_m < 0.3


def test_one_vehicle_team_flies_like_a_single_search():
    r = fly_team_offline(SCENE, 1, seed=2)
    assert r.brain.final is not None and r.brain.final.outcome.found
    assert math.isinf(r.min_separation_m)


@pytest.mark.slow
def test_team_ellipse_coverage_is_honest():
    """The joint 95 % ellipse holds the truth in k of n flights, k ~ Binomial(n, 0.95) if honest; with n = 8,
    P(k <= 5) = 0.6 %: fewer than 6 covered would say the joint fit claims more than it knows."""
    n = 8
    covered = []
    for seed in range(100, 100 + n):
        r = fly_team_offline(SCENE, 2, seed=seed)
        src = r.dataset.truth.sources[0]
        covered.append(bool(coverage(r.estimate, (src.x, src.y))[1]))
    assert stats.binom.cdf(5, n, 0.95) < 0.01
    assert sum(covered) >= 6, covered


@pytest.mark.slow
def test_the_same_seed_flies_the_same_team_flight():
    """The vehicles step on one sim clock and claims are stamped with sim time: nothing depends on wall time."""
    a, b = (fly_team_offline(SCENE, 2, seed=4) for _ in range(2))
    assert [d.reason for d in a.decisions] == [d.reason for d in b.decisions]
    fa, fb = a.dataset.frames, b.dataset.frames
    assert len(fa) == len(fb) > 100
    assert (fa.t == fb.t).all() and (fa.positions == fb.positions).all() and (fa.counts == fb.counts).all()
    assert a.error_m == b.error_m


def test_three_vehicles_keep_their_separation_from_the_start():
    """A teammate still taking off has said no reservation: it is not reserved at a made-up point, and no plan
    is made before every teammate has said where it starts (seed 16 flew two vehicles 7 mm apart when a
    taking-off teammate's first status counted as its start)."""
    r = fly_team_offline(SCENE, 3, seed=16)
    assert all(s is not None and s["outcome"] == "found" for s in r.summaries), r.log
    assert r.min_separation_est_m >= TeamConfig().separation_m - 1e-9
    assert r.min_separation_m >= TeamConfig().separation_m - 5 * 0.03 * math.sqrt(40)
