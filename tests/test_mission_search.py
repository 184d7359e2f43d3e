"""The search brain flown in-process against the emulator, and the truth-isolation rule."""

import math

import numpy as np
import pytest

from detector_fw_sim.scene import load_scene
from launch.offline import fly_offline
from mission.search import Outcome, Phase, SearchConfig
from tests.support.offline_flights import default_flight


@pytest.mark.parametrize("seed", [1, 2])
def test_search_finds_the_default_source(seed, tmp_path_factory):
    r = default_flight(tmp_path_factory, seed)
    assert r.decisions[-1].phase is Phase.DONE
    assert len(r.dwell_rates) <= SearchConfig().max_dwells
    # exploration ends only with three readings above background, then the estimate drives the search
    assert r.brain.search_dwells >= SearchConfig().min_search_dwells
    est = r.estimate
    # bound: the stop rule asks 1-sigma < 0.1 m; odometry drift (0.03 m/sqrt(m) over ~30 m, about 0.16 m)
    # adds an error the estimator cannot see, so 0.5 m is ~3 sigma of the two combined
    assert r.error_m < 0.5, (est, r.log)
    assert est.cps_at_1m == pytest.approx(1600, rel=0.25)
    # one sigma: the stop rule's is the estimate record's (estimator.inflight.sigma_m), which replay reproduces
    last = r.decisions[-1]
    if last.outcome.found:
        # below the stop rule, or drift-limited: within 25 % of the floor the odometry drift allows
        limit = 1.25 * est.drift_floor_m if last.outcome is Outcome.DRIFT_LIMITED else SearchConfig().stop_sigma_m
        assert est.sigma_m < limit
        assert f"1-sigma {est.sigma_m:.3f} m" in last.reason
        assert last.reason.startswith("source found")  # the text for people says it too
    # the recorded flight is a valid dataset whose dwell frames sit at the reported dwell positions
    f = r.dataset.frames
    for k, pos in enumerate(r.dwell_positions):
        m = f.dwell == k
        assert m.sum() >= 40  # >= t_min of 5 s at 10 Hz (fewer would mean frames were lost)
        assert np.allclose(f.positions[m].mean(0), pos, atol=0.05)


@pytest.mark.slow
def test_the_same_seed_flies_the_same_search_after_other_flights():
    # campaigns fly many seeds in one worker process: seed 2 flown after seed 1 must be seed 2 flown first
    # (the trees are node-bounded and OMPL's seed sequence restarts per flight), so any row is reproducible
    first = fly_offline(load_scene(), SearchConfig(), seed=2)
    fly_offline(load_scene(), SearchConfig(), seed=1)
    again = fly_offline(load_scene(), SearchConfig(), seed=2)
    np.testing.assert_array_equal(first.dataset.frames.positions, again.dataset.frames.positions)
    np.testing.assert_array_equal(first.dataset.frames.counts, again.dataset.frames.counts)
    assert first.error_m == again.error_m
    assert [d.reason for d in first.decisions] == [d.reason for d in again.decisions]


def _misfit_everywhere(monkeypatch):
    """The injected fault: every in-flight fit reports a failed goodness of fit (p = 0)."""
    import estimator.inflight as inflight

    update = inflight.InflightEstimator.update

    def misfit(self, frames, dwell):
        rec = update(self, frames, dwell)
        if rec is not None:
            rec["p_value"] = 0.0
        return rec

    monkeypatch.setattr(inflight.InflightEstimator, "update", misfit)


def test_a_fit_that_misses_the_counts_is_no_found_source(monkeypatch, tmp_path_factory):
    """Same seed, same flight up to the stop: the honest fit stops "source found"; when every fit fails its
    goodness of fit the search flies on to its budget and says why."""
    config = SearchConfig()
    honest = default_flight(tmp_path_factory, 1)
    assert honest.decisions[-1].outcome.found
    _misfit_everywhere(monkeypatch)
    r = fly_offline(load_scene(), config, seed=1)
    assert [d.outcome for d in r.decisions[:-1]] == [None] * (len(r.decisions) - 1)
    assert r.decisions[-1].outcome is Outcome.MISFIT
    assert r.decisions[-1].reason.startswith("dwell budget spent")
    assert "the model misses something, fit p = 0" in r.decisions[-1].reason
    assert r.brain.search_dwells > honest.brain.search_dwells


def test_no_valid_next_best_point_explores_instead_of_giving_up(monkeypatch):
    """The injected fault: the first next-best planning finds no valid node (as when a broad early belief
    covers the whole tree); the brain explores and the search goes on."""
    import mission.search as ms
    from planner.plan import DwellPlan

    plan = ms.plan_next_dwell
    calls = []

    def none_first(*args, **kwargs):
        calls.append(1)
        if len(calls) == 1:
            return DwellPlan(np.zeros((0, 4)), np.zeros((0, 4)), "next_best_eq6")
        return plan(*args, **kwargs)

    monkeypatch.setattr(ms, "plan_next_dwell", none_first)
    r = fly_offline(load_scene(), SearchConfig(), seed=1)
    fallback = [d for d in r.decisions if d.reason.startswith("no valid next-best dwell point")]
    assert len(fallback) == 1 and fallback[0].phase is Phase.EXPLORE and fallback[0].plan.ok
    assert len(calls) >= 2 and r.decisions[-1].phase is Phase.DONE
    assert r.brain.estimate is not None


@pytest.mark.parametrize(("sigmas", "floor", "dwells", "limited", "pose_sd"), [
    ((0.137, 0.137), 0.137, (8, 9), True, 0.15),  # outdoor seed 13: at the floor, no longer falling
    ((0.149, 0.137), 0.137, (8, 9), False, 0.15),  # still falling by 8 % a dwell
    ((0.159, 0.157), 0.100, (6, 7), False, 0.15),  # plateau well above the drift floor: something else limits it
    ((0.159, 0.157), 0.157, (5, 7), False, 0.15),  # a dwell without an estimate in between
    ((math.inf, 0.157), 0.157, (6, 7), False, 0.15),  # the previous estimate was untrustworthy
    ((0.159, 0.157), math.nan, (6, 7), False, 0.15),  # no drift bound (another localizer)
    ((0.157,), 0.157, (7,), False, 0.15),  # one estimate says nothing about falling
    ((0.152, 0.182, 0.159), 0.142, (7, 8, 9), True, 0.15),  # real stack outdoor: scatter at the floor, not falling
    ((0.182, 0.152, 0.150), 0.142, (7, 8, 9), True, 0.15),  # fell, then stopped falling
    ((0.200, 0.182, 0.159), 0.142, (7, 8, 9), False, 0.15),  # falling by 13 % on the best before it
    ((math.inf, 0.182, 0.159), 0.142, (7, 8, 9), False, 0.15),  # an untrustworthy estimate among the two before
    ((0.152, 0.182, 0.159), 0.142, (5, 8, 9), False, 0.15),  # dwell 5 is too old: against 8 alone it fell 13 %
    ((6.95, 6.95), 6.95, (4, 5), False, 0.15),  # outdoor: a geometry floor 46x the drift is no drift floor
    ((0.137, 0.137), 0.137, (8, 9), False, math.nan),  # no reported pose variance: no drift floor either
])
def test_drift_limited_rule(sigmas, floor, dwells, limited, pose_sd):
    from estimator.inflight import InflightEstimator
    from mission.search import SearchBrain

    brain = SearchBrain(load_scene("outdoor").scenario())
    brain.estimator = InflightEstimator(brain.scenario)
    brain.estimator.estimates = [{"dwell": d, "x": 1.0, "y": 2.0, "z": 0.0, "cps_at_1m": 1000.0,
                                  "background_cps": 30.0, "covariance": np.eye(3).tolist(), "sigma_m": s,
                                  "drift_floor_m": floor, "pose_sd_m": pose_sd}
                                 for d, s in zip(dwells, sigmas, strict=True)]
    assert brain._drift_limited() == (floor if limited else 0.0)


@pytest.mark.parametrize("at_floor", [True, False])
def test_the_drift_limited_stop_can_be_switched_off(at_floor):
    """At the floor (outdoor seed 13's state above) the rule stops "drift-limited"; with the stop switched off
    (``benchmarks/error_along_flight.py`` flies on to see what more dwells buy) the same state flies on."""
    from estimator.inflight import InflightEstimator
    from mission.search import SearchBrain, belief_of

    brain = SearchBrain(load_scene("outdoor").scenario(), SearchConfig(stop_at_drift_floor=at_floor))
    brain.estimator = InflightEstimator(brain.scenario)
    brain.estimator.estimates = [{"dwell": d, "x": 1.0, "y": 2.0, "z": 0.0, "cps_at_1m": 1000.0,
                                  "background_cps": 30.0, "covariance": (0.01 * np.eye(3)).tolist(),
                                  "sigma_m": 0.137, "drift_floor_m": 0.137, "pose_sd_m": 0.15, "p_value": 0.5}
                                 for d in (8, 9)]
    brain.search_dwells = 3
    stop = brain.stop_rule(belief_of(brain.estimate), 0.137)
    if at_floor:
        assert stop is not None and stop[1] is Outcome.DRIFT_LIMITED
    else:
        assert stop is None


@pytest.mark.slow  # one whole outdoor search: ~5 s of CPU
def test_an_outdoor_search_begun_far_from_the_source_is_not_ended_by_its_unlocalised_dwells():
    """Issue 36 item 2, outdoor seed 5: exploration ends 10-20 m from the 60000 cps source, so the first search
    estimates have a 1-sigma of metres and the dwells planned from them aim at nothing yet. Counted against
    ``max_search_dwells`` they end this flight "dwell budget spent" after 6 (1-sigma 0.159 m, error 0.105 m: the
    rule before d33f0fc, checked by counting every search dwell); the search must fly on until a stop rule holds.
    (Seed 49 was this case until the fits stopped polishing minima within NEAR_MINIMUM_EDM; it now reaches the
    drift floor in 5 search dwells. Seed 5 is the first of outdoor seeds 0-119 with two or more wide estimates that
    flies past the budget.)"""
    from launch.campaign import coverage
    from mission.search import LOCALISED_M

    cfg = SearchConfig(strategy="active")
    r = fly_offline(load_scene("outdoor"), cfg, seed=5)
    wide = sum(not e.sigma_m < LOCALISED_M for e in r.brain.estimates[:-1])
    # what makes this flight the case: search dwells planned from unlocalised beliefs
    assert wide >= 2, [e.sigma_m for e in r.brain.estimates]
    last = r.decisions[-1]
    assert last.outcome.found, last.reason
    # found only by flying past the search budget those dwells would have spent; the battery still bounds it
    assert cfg.max_search_dwells < r.brain.search_dwells and len(r.brain.history) <= cfg.max_dwells
    # and what it reports as found is honest: the truth inside the final ellipse's 99.9 % region (chi2, 2 dof)
    src = r.dataset.truth.sources[0]
    d2, _ = coverage(r.estimate, (src.x, src.y))
    assert d2 <= -2.0 * math.log(1e-3), (d2, r.error_m)
