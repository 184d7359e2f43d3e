"""The second-source test sent at the stop (``InflightEstimator.recheck``, ``SearchBrain``): a one-source estimate
whose trigger stayed quiet (fit adequate, background excess below ``BACKGROUND_EXCESS_Z``) is tested once more before
the search stops found. Analytic flights (exact expected counts) and the two-source scene in flight (seed 19)."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.analytic_flights import dwell_frames, lattice_points, scenario_for
from estimator.inflight import BACKGROUND_EXCESS_Z, SECOND_SOURCE_TRY_P, InflightEstimator

PRIMARY = (3.6, 5.2, 0.0, 2200.0)
SECOND_XY = np.array([8.1, 3.0])


def _flight(second_cps: float):
    """The lattice around the primary and two dwells beside a weak second source 5 m away."""
    pts = np.vstack([lattice_points(PRIMARY[:2]), [[7.0, 3.5, 1.5], [8.5, 2.0, 1.5]]])
    sources = [PRIMARY] + ([(*SECOND_XY, 0.0, second_cps)] if second_cps else [])
    return pts, dwell_frames(pts, sources, 30.0, dwell_s=10.0, exact=True)


def test_a_second_source_the_trigger_missed_is_found_at_the_stop():
    """60 cps at 1 m beside 2200: the one-source fit is adequate and its background stands 2.9 sd above the
    operator's (under the 3.09 trigger), so no test was sent; sent at the stop, it passes, and the two-source record
    replaces the one-source one (same dwell, one record)."""
    pts, frames = _flight(60.0)
    est = InflightEstimator(scenario_for(bounds_max=(12.0, 9.0, 0.5)))
    one = est.update(frames, dwell=len(pts))
    assert one["effects"] == [] and one["p_value"] > SECOND_SOURCE_TRY_P
    assert 2.0 < one["background_excess_z"] < BACKGROUND_EXCESS_Z
    assert est.recheck(frames, len(pts))
    assert len(est.estimates) == 1 and est.estimate["dwell"] == len(pts)
    assert est.estimate["effects"] == ["second_source"]
    p = est.estimate["params"]
    assert np.hypot(p["second_source.x"] - SECOND_XY[0], p["second_source.y"] - SECOND_XY[1]) < 1.5
    assert np.hypot(est.estimate["x"] - PRIMARY[0], est.estimate["y"] - PRIMARY[1]) < 0.05


def test_without_a_second_source_the_record_stays_as_it_was():
    pts, frames = _flight(0.0)
    est = InflightEstimator(scenario_for(bounds_max=(12.0, 9.0, 0.5)))
    one = est.update(frames, dwell=len(pts))
    assert not est.recheck(frames, len(pts))
    assert est.estimates == [one]


@pytest.mark.slow
def test_the_two_source_flight_the_trigger_left_one_sourced(monkeypatch):
    """Two-source seed 19 (information planner, in process): without the test at the stop the search ended on one
    source 0.32 m off at a 1-sigma of 0.10 m (outside its 95 % ellipse); with it the second source is fitted, the
    search goes on from that estimate, and the primary is inside its ellipse."""
    from detector_fw_sim.scene import load_scene
    from launch.campaign import coverage
    from launch.offline import fly_offline
    from mission.search import Outcome, SearchConfig

    scene = load_scene("two-source")
    config = SearchConfig(strategy="info")
    with_test = fly_offline(scene, config, seed=19)
    monkeypatch.setattr(InflightEstimator, "recheck", lambda self, frames, dwell: False)
    without = fly_offline(scene, config, seed=19)
    last, old = with_test.brain.estimator.estimate, without.brain.estimator.estimate
    assert old["effects"] == [] and without.error_m > 0.25
    assert coverage(without.brain.estimate, PRIMARY[:2])[1] is False
    assert last["effects"] == ["second_source"] and with_test.error_m < 0.15
    assert coverage(with_test.brain.estimate, PRIMARY[:2])[1] is True
    assert with_test.decisions[-1].outcome in (Outcome.FOUND, Outcome.DRIFT_LIMITED)
