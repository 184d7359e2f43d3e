"""Every ``radseek.outcome.Outcome`` of ``mission.search`` comes from the stop rule that makes it (issue 31 item 3):
the brain driven one dwell at a time with the in-flight fit stubbed (no fits, no planning trees)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

import mission.search as ms
from detector_fw_sim.scene import load_scene
from mission.search import Outcome, Phase, SearchBrain, SearchConfig, search_failure
from planner.belief import DwellHistory
from planner.plan import DwellPlan
from radseek import topics
from radseek.outcome import parse_outcome

SCENARIO = load_scene("default").scenario()
FRAMES = SimpleNamespace(positions=None, pose_variances=None, dwell=None)  # only the stubbed fit sees them
STATUS = SimpleNamespace(mean_rate=40.0)
HERE = np.array([1.0, 1.0, 1.5, 0.0])


def _record(dwell: int, sigma: float, p_value: float = 0.5, floor: float = math.nan, x: float = 4.3) -> dict:
    return {"dwell": dwell, "x": x, "y": 3.7, "z": 0.0, "cps_at_1m": 1600.0, "background_cps": 30.0,
            "covariance": np.diag([sigma**2, sigma**2, 0.01]).tolist(), "sigma_m": sigma, "effects": [], "params": {},
            "converged": True, "p_value": p_value, "drift_floor_m": floor, "pose_sd_m": 0.15}


def _brain(monkeypatch, fits: list[dict | None], strategy: str = "active", search_dwells: int = 3) -> SearchBrain:
    """A brain in its search phase whose in-flight fit returns ``fits`` in turn (after the estimates of
    ``fits[:-1]``, already made)."""
    monkeypatch.setattr(ms, "drift_density_from_poses", lambda *a: 0.0)
    brain = SearchBrain(SCENARIO, SearchConfig(strategy=strategy))
    brain.phase, brain.search_dwells = Phase.SEARCH, search_dwells
    brain.estimator.estimates = [f for f in fits[:-1] if f is not None]

    def update(frames, dwell):
        if fits[-1] is not None:
            brain.estimator.estimates.append(fits[-1])
        return fits[-1]

    monkeypatch.setattr(brain.estimator, "update", update)
    return brain


def _stop(brain: SearchBrain) -> ms.Decision:
    d = brain.end_dwell(np.array([2.0, 2.0, 1.5]), STATUS, FRAMES, HERE)
    assert d.phase is Phase.DONE and d.plan is None, d.reason
    return d


def test_found(monkeypatch):
    d = _stop(_brain(monkeypatch, [_record(5, 0.06), _record(6, 0.05)]))
    assert d.outcome is Outcome.FOUND and d.outcome.found and d.reason.startswith("source found")


def test_drift_limited(monkeypatch):
    d = _stop(_brain(monkeypatch, [_record(8, 0.137, floor=0.137), _record(9, 0.137, floor=0.137)]))
    assert d.outcome is Outcome.DRIFT_LIMITED and d.outcome.found and "drift-limited" in d.reason


def test_budget_spent_and_misfit(monkeypatch):
    cfg = SearchConfig()
    d = _stop(_brain(monkeypatch, [_record(8, 0.5)], search_dwells=cfg.max_search_dwells))
    assert d.outcome is Outcome.BUDGET_SPENT and not d.outcome.found
    # the same small ellipse that would be found, but the model misses the counts: spent, and why
    d = _stop(_brain(monkeypatch, [_record(5, 0.06, p_value=0.0), _record(6, 0.05, p_value=0.0)],
                     search_dwells=cfg.max_search_dwells))
    assert d.outcome is Outcome.MISFIT and "the model misses something" in d.reason


def test_search_dwells_planned_from_an_unlocalised_belief_do_not_spend_the_budget(monkeypatch):
    # max_search_dwells flown, the first three planned from estimates of 1-sigma 20, 20 and 5 m (outdoor: the
    # search begins 10-20 m from the source): three dwells of the budget are left, the search goes on
    n = SearchConfig().max_search_dwells
    wide = [_record(3, 20.0), _record(4, 20.0), _record(5, 5.0)]
    narrow = [_record(6 + k, 0.5) for k in range(n - 2)]
    brain = _brain(monkeypatch, wide + narrow, search_dwells=n)
    brain.estimator.estimates.append(narrow[-1])  # the estimate after the last dwell
    assert brain.stop_rule(None, 0.5) is None
    # the same count planned from localised beliefs spends it
    brain = _brain(monkeypatch, [_record(3 + k, 0.9) for k in range(n + 1)], search_dwells=n)
    brain.estimator.estimates.append(_record(3 + n, 0.9))
    assert brain.stop_rule(None, 0.9)[1] is Outcome.BUDGET_SPENT
    # and the battery's max_dwells bounds the unlocalised search all the same
    brain = _brain(monkeypatch, wide + narrow, search_dwells=n)
    brain.estimator.estimates.append(narrow[-1])
    brain.history = DwellHistory(np.zeros((SearchConfig().max_dwells, 3)), np.zeros(SearchConfig().max_dwells))
    assert brain.stop_rule(None, 0.5)[1] is Outcome.BUDGET_SPENT


def test_budget_spent_during_exploration(monkeypatch):
    brain = _brain(monkeypatch, [None])
    n = brain.config.max_dwells - 1
    brain.phase, brain.history = Phase.EXPLORE, DwellHistory(np.zeros((n, 3)), np.zeros(n))
    d = _stop(brain)
    assert d.outcome is Outcome.BUDGET_SPENT and d.reason == "dwell budget spent during exploration"


def test_no_frontier(monkeypatch):
    monkeypatch.setattr(ms, "plan_exploration", lambda *a, **k: DwellPlan(np.zeros((0, 4)), np.zeros((0, 4)), "x"))
    d = SearchBrain(SCENARIO).start(HERE)
    assert d.phase is Phase.DONE and d.outcome is Outcome.NO_FRONTIER


def test_pattern_flown(monkeypatch):
    brain = _brain(monkeypatch, [None], strategy="lattice")
    brain.phase, brain.pattern = Phase.PATTERN, []
    d = _stop(brain)
    assert d.outcome is Outcome.PATTERN_FLOWN and d.outcome.located and not d.outcome.found


def test_a_search_that_goes_on_has_no_outcome(monkeypatch):
    d = SearchBrain(SCENARIO).start(HERE)
    assert d.phase is Phase.EXPLORE and d.outcome is None


@pytest.mark.parametrize(("outcome", "failed"), [
    (Outcome.FOUND, False), (Outcome.DRIFT_LIMITED, False), (Outcome.PATTERN_FLOWN, False),
    (Outcome.BUDGET_SPENT, True), (Outcome.MISFIT, True), (Outcome.NO_FRONTIER, True), (Outcome.ABORTED, True),
    (Outcome.RETIRED, True), (None, True),
])
def test_search_failure_is_the_outcome(outcome, failed):
    summary = {"reason": "some text", "outcome": outcome, "estimate": {"x": 0.0}}
    assert (search_failure(summary) is not None) == failed
    if outcome is not None and outcome.aborted:
        assert search_failure(summary) == "some text"


def test_parse_outcome_and_the_team_status_field():
    assert parse_outcome("found") is Outcome.FOUND and parse_outcome("") is None and parse_outcome(None) is None
    assert parse_outcome("source found") is None  # the text is never read back
    st = topics.TeamStatus(t=1.0, vehicle="uav0", seq=0, state="done", reservation=[0.0, 0.0, 1.5],
                           reason="source found: 1-sigma 0.05 m < 0.1 m", decided=True, outcome=Outcome.FOUND)
    back = topics.TeamStatus.from_bytes(st.to_bytes())
    assert parse_outcome(back.outcome) is Outcome.FOUND
    assert topics.TeamStatus.from_dict({k: v for k, v in st.to_dict().items() if k != "outcome"}).outcome == ""
    with pytest.raises(topics.PayloadError, match="outcome"):
        topics.TeamStatus.from_dict({**st.to_dict(), "outcome": "source found"})


def _info_brain(monkeypatch, fall: float, bound: float = 0.05, **config) -> SearchBrain:
    """An info search after two stable, fitting estimates of 1-sigma 0.137 m (above the 0.10 m target, at a
    landmark-free drift floor of 0.137 m) whose planner expects its best next leg to take ``fall`` m/s off the
    flown frames' bound ``bound``."""
    brain = _brain(monkeypatch, [_record(8, 0.137, floor=0.137), _record(9, 0.137, floor=0.137)], strategy="info")
    brain.config = SearchConfig(strategy="info", **config)
    plan = DwellPlan(np.array([[3.0, 3.0, 1.5, 0.0]]), np.array([[1.0, 1.0, 1.5, 0.0], [3.0, 3.0, 1.5, 0.0]]),
                     "next_best_info", info={"bound_m": bound, "bound_fall_m_s": fall, "dwell_s": 5.0})
    monkeypatch.setattr(brain, "_plan_next", lambda current, frames, belief: plan)
    return brain


def test_the_info_search_stops_drift_limited_when_the_next_leg_would_hardly_lower_the_bound(monkeypatch):
    limit = SearchConfig().bound_fall_m_s
    d = _stop(_info_brain(monkeypatch, 0.5 * limit))
    assert d.outcome is Outcome.DRIFT_LIMITED and "0.050 m" in d.reason and "per second" in d.reason
    # the same estimates at the landmark-free floor, but a next leg still worth flying: no stop (the old rule
    # would have stopped here), the planned leg is flown
    brain = _info_brain(monkeypatch, 2.0 * limit)
    d = brain.end_dwell(np.array([2.0, 2.0, 1.5]), STATUS, FRAMES, HERE)
    assert d.phase is Phase.SEARCH and d.plan is not None and d.outcome is None
    assert brain.bound_falls[-1] == (1, 0.05, 2.0 * limit)
    # no valid next leg (nan) is no reason to stop; switched off, the rule never stops
    for fall, config in ((math.nan, {}), (0.0, {"bound_fall_m_s": 0.0}), (0.0, {"stop_at_drift_floor": False})):
        d = _info_brain(monkeypatch, fall, **config).end_dwell(np.array([2.0, 2.0, 1.5]), STATUS, FRAMES, HERE)
        assert d.phase is Phase.SEARCH and d.outcome is None, (fall, config)
    with pytest.raises(ValueError, match="bound_fall_m_s"):
        SearchConfig(bound_fall_m_s=-1.0)


def test_the_bound_fall_stop_needs_a_searched_stable_fitting_localised_estimate(monkeypatch):
    limit = SearchConfig().bound_fall_m_s
    brain = _info_brain(monkeypatch, 0.0)
    brain.estimator.estimates = [_record(8, 0.137), _record(9, 0.137)]
    belief = ms.belief_of(ms.SourceEstimate.from_json(_record(9, 0.137)))
    assert brain.stop_rule(belief, 0.137, 0.0)[1] is Outcome.DRIFT_LIMITED
    # misfit, unstable (the estimate jumped 3 m), not localised (1-sigma >= 1 m), too few search dwells
    brain.estimator.estimates = [_record(8, 0.137, p_value=0.0), _record(9, 0.137, p_value=0.0)]
    assert brain.stop_rule(belief, 0.137, 0.0) is None
    brain.estimator.estimates = [_record(8, 0.137, x=1.3), _record(9, 0.137)]
    assert brain.stop_rule(belief, 0.137, 0.0) is None
    brain.estimator.estimates = [_record(8, 0.137), _record(9, 0.137)]
    assert brain.stop_rule(belief, 1.2, 0.0) is None
    brain.search_dwells = brain.config.min_search_dwells - 1
    assert brain.stop_rule(belief, 0.137, 0.5 * limit) is None


@pytest.mark.parametrize(("strategy", "readings", "searching"), [
    ("info", 1, False), ("info", 2, True), ("active", 2, False), ("active", 3, True)])
def test_the_info_search_ends_exploration_after_two_readings_above_background(monkeypatch, strategy, readings,
                                                                               searching):
    # a dwell ends with ``readings`` dwell rates 3x background (far above the 3-sigma test): the info search
    # searches after two (each exploration dwell adds drift to the counts its score plans for), paper 003's
    # active search after three; exploring on, the reason counts towards the strategy's number
    brain = _brain(monkeypatch, [None], strategy=strategy)
    brain.phase = Phase.EXPLORE
    monkeypatch.setattr(ms, "plan_exploration", lambda *a, **k: DwellPlan(
        np.array([[3.0, 3.0, 1.5, 0.0]]), np.array([[1.0, 1.0, 1.5, 0.0], [3.0, 3.0, 1.5, 0.0]]), "frontier"))
    bg = SCENARIO.background_cps
    n = readings - 1
    brain.history = DwellHistory(np.zeros((n, 3)), np.full(n, 3 * bg))
    brain.end_dwell(np.array([2.0, 2.0, 1.5]), SimpleNamespace(mean_rate=3 * bg), FRAMES, HERE)
    assert (brain.phase is Phase.SEARCH) == searching
    if not searching:
        assert brain.config.exploration.min_readings == readings + 1
    with pytest.raises(ValueError, match="info_min_readings"):
        SearchConfig(info_min_readings=0)


def test_an_info_search_whose_budget_is_spent_at_a_good_estimate_is_drift_limited(monkeypatch):
    # no next leg can be flown, so the bound has fallen as far as this flight allows: a stable, fitting, localised
    # estimate is found (drift-limited) however much a next leg would have bought; a misfit is still the budget's
    limit = SearchConfig().bound_fall_m_s
    n = SearchConfig().max_search_dwells
    brain = _info_brain(monkeypatch, 10 * limit)
    brain.search_dwells = n - 1  # the dwell that ends now is the budget's last
    d = _stop(brain)
    assert d.outcome is Outcome.DRIFT_LIMITED and "the dwell budget allows no next leg" in d.reason
    brain = _info_brain(monkeypatch, 10 * limit)
    brain.search_dwells = n - 1
    brain.estimator.estimates = [_record(8, 0.137, p_value=0.0)]
    monkeypatch.setattr(brain.estimator, "update", lambda frames, dwell: brain.estimator.estimates.append(
        _record(9, 0.137, p_value=0.0)) or brain.estimator.estimates[-1])
    assert _stop(brain).outcome is Outcome.MISFIT


def _two_source_record(dwell: int, order_z: float) -> dict:
    """A fitting, stable, localised two-source record (the stronger fitted source at (4.3, 3.7)) whose strength
    stands ``order_z`` sd above the other's, at (8.1, 3.0)."""
    return {**_record(dwell, 0.05), "effects": ["second_source"], "strength_order_z": order_z,
            "params": {"second_source.x": 8.1, "second_source.y": 3.0, "second_source.cps_at_1m": 1300.0}}


def _two_source_brain(monkeypatch, order_z: float, sds: tuple[float, float] = (70.0, 590.0),
                      **kwargs) -> tuple[SearchBrain, list]:
    """An active search after two such records; the last fit's localizer holds both sources (the record's
    first), their strengths' sd ``sds``; the planner records the belief it is asked to plan for."""
    brain = _brain(monkeypatch, [_two_source_record(5, order_z), _two_source_record(6, order_z)], **kwargs)
    cov = np.diag([0.05**2, 0.05**2, 0.01, sds[0]**2, 0.6**2, 0.5**2, 0.01, sds[1]**2])
    brain.estimator.localizer = SimpleNamespace(
        sources_=[{"x": 4.3, "y": 3.7, "z": 0.0, "cps_at_1m": 1600.0}, {"x": 8.1, "y": 3.0, "z": 0.0,
                                                                       "cps_at_1m": 1300.0}], covariance_=cov)
    beliefs = []
    plan = DwellPlan(np.array([[7.0, 3.0, 1.5, 0.0]]), np.array([[1.0, 1.0, 1.5, 0.0], [7.0, 3.0, 1.5, 0.0]]),
                     "next_best")
    monkeypatch.setattr(brain, "_plan_next", lambda current, frames, belief: beliefs.append(belief) or plan)
    return brain, beliefs


def test_a_two_source_estimate_is_found_only_once_the_counts_decide_which_source_is_the_stronger(monkeypatch):
    # two-source seed 160: the search stopped "found" on the source fitted 1364 +- 73 cps, the other 1040 +- 592
    # (0.5 sd apart), and reported the weaker source. Undecided: no stop, and the next dwell is planned for the
    # source whose strength is the less known (there the other), whose counts decide the order
    brain, beliefs = _two_source_brain(monkeypatch, 0.5)
    d = brain.end_dwell(np.array([2.0, 2.0, 1.5]), STATUS, FRAMES, HERE)
    assert d.phase is Phase.SEARCH and d.outcome is None, d.reason
    np.testing.assert_allclose(beliefs[-1].mean, [8.1, 3.0, 0.0])
    assert beliefs[-1].cps_at_1m == 1300.0
    np.testing.assert_allclose(np.diag(beliefs[-1].covariance), [0.36, 0.25, 0.01])
    # seed 6: a far second source fitted stronger than the true one, its strength the less known: planned for
    brain, beliefs = _two_source_brain(monkeypatch, 0.9, sds=(1500.0, 70.0))
    assert brain.end_dwell(np.array([2.0, 2.0, 1.5]), STATUS, FRAMES, HERE).outcome is None
    np.testing.assert_allclose(beliefs[-1].mean, [4.3, 3.7, 0.0])
    assert beliefs[-1].cps_at_1m == 1600.0
    # the same estimate decided (and with the order unknown: an unconverged fit has no covariance)
    brain, beliefs = _two_source_brain(monkeypatch, 2.5)
    assert _stop(brain).outcome is Outcome.FOUND and not beliefs
    brain, _ = _two_source_brain(monkeypatch, math.nan)
    assert brain.end_dwell(np.array([2.0, 2.0, 1.5]), STATUS, FRAMES, HERE).outcome is None
    # undecided when the budget is spent: spent, and why
    brain, _ = _two_source_brain(monkeypatch, 0.5, search_dwells=SearchConfig().max_search_dwells)
    d = _stop(brain)
    assert d.outcome is Outcome.BUDGET_SPENT and "which source is the stronger is undecided (0.5 sd)" in d.reason
