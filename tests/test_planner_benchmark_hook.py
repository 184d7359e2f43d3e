"""The error-vs-dwell-points benchmark loop runs with injected measure/localize callables.

The benchmark is our own code: if it cannot be imported the test fails (a collection error), never skips."""

import numpy as np
import pytest

from benchmarks import planner_vs_baselines as pvb
from planner.belief import SourceBelief
from planner.occupancy import OccupancyMap


def test_run_episode_uses_only_the_injected_callables_and_stops_at_the_target():
    occ = OccupancyMap(np.array([0.0, 0.0, 0.5]), np.array([10.0, 8.0, 2.5]), (), 0.3)
    source = np.array([6.0, 5.0, 0.0])
    calls = {"measure": 0, "localize": 0}

    def measure(point, yaw):  # noise-free inverse square + 30 cps, 5 s dwells
        calls["measure"] += 1
        return 1000.0 / float(((point - source) ** 2).sum()) + 30.0, 5.0

    def localize(history):  # an oracle that improves with every dwell: error 1.0, 0.5, 0.25 m, ...
        calls["localize"] += 1
        if len(history) < 3:
            return None
        err = 2.0 ** -(len(history) - 3)
        return SourceBelief(source + [err, 0.0, 0.0], np.eye(3) * 0.01, 1000.0, 30.0)

    for strategy in ("next-best", "lattice", "pre"):
        calls.update(measure=0, localize=0)
        ep = pvb.run_episode(strategy, occ, np.array([0.6, 0.6, 1.5, 0.0]), 30.0, measure, localize,
                             lambda b: float(np.linalg.norm(b.mean - source)), np.random.default_rng(0))
        assert ep.reached and ep.stop == "target"
        assert ep.dwells == 5 == calls["measure"] == calls["localize"]  # 0.25 m < 0.3 m at the 5th dwell
        assert ep.mission_time >= 5 * 5.0
        assert np.isnan(ep.errors[:2]).all() and ep.errors[-1] == pytest.approx(0.25)


@pytest.mark.slow
def test_a_flight_with_the_stop_rule_off_is_the_stopped_flight_flown_on():
    """benchmarks/error_along_flight reads "the last estimate by t" as what a stop rule stopping by t reports:
    the planner never looks at the stop rule, so the stopped flight must be the open one cut at its stop."""
    from benchmarks.error_along_flight import error_by, fly
    from detector_fw_sim.scene import load_scene
    from launch.offline import fly_offline
    from mission.search import SearchConfig

    stopped = fly_offline(load_scene(), SearchConfig(strategy="info"), seed=1)
    row = fly("default", "info", 1, max_search_dwells=8)
    n = len(stopped.brain.estimates)
    assert len(row["along"]) > n  # it flew on past the stop
    for a, e in zip(row["along"][:n], stopped.brain.estimates, strict=True):
        assert a["dwell"] == e.dwell
        assert a["sigma_m"] == pytest.approx(e.sigma_m, rel=1e-9)
    # its estimate at the stop's mission time is the stopped flight's answer, and nothing later is
    assert row["along"][n - 1]["t"] == pytest.approx(stopped.mission_time_s, abs=0.05)
    assert error_by(row, stopped.mission_time_s + 0.05) == pytest.approx(stopped.error_m, rel=1e-6)
    assert row["along"][n]["t"] > stopped.mission_time_s + 1.0
