"""Lockstep makes a flight reproducible: `radseek run` twice with the same seed (the two flights at the
same time, so they also compete for the CPU differently) gives the same summary and the same recorded
frames, even though the second is attacked while it flies (forged clock, lockstep and histograms from processes
holding some of the run's passwords). Only wall-clock fields may differ. A fast honest configuration: default
scene, 50x, 4 dwells (tests/support/same_seed_runs.py: the two runs are flown once per test run; test_one_world
reads the first, test_run_mcap the second)."""

import json

import pytest

from mission.search import search_failure
from tests.support.same_seed_runs import MAX_DWELLS, RUN_TIMEOUT_S, same_seed_runs

pytestmark = [pytest.mark.slow, pytest.mark.io, pytest.mark.timeout(RUN_TIMEOUT_S + 120)]
#: the only fields allowed to differ: wall time, and the transport's sample accounting (status keys are also sent
#: once per wall second, and the queue's high-water mark depends on scheduling); the flight's own keys' counts are
#: compared on their own below
WALL_FIELDS = {"wall_time_s", "samples", "histogram_queue"}


def _without_wall(d: dict) -> dict:
    return {k: v for k, v in d.items() if k not in WALL_FIELDS}


def test_same_seed_same_flight(tmp_path_factory):
    runs = same_seed_runs(tmp_path_factory)  # also read by test_one_world
    outs = runs["outs"]
    for code, err, o in zip(runs["codes"], runs["errs"], outs, strict=True):
        assert code in (0, 3), err[-3000:]  # 3: searched to the end of the 4-dwell budget
        # the exit code is the mission's verdict, said by `radseek mission` itself (exit 3, logged) and by run
        failure = search_failure(json.loads((o / "dataset" / "mission_summary.json").read_text()))
        assert code == (0 if failure is None else 3), err[-3000:]
        assert "disagrees with its summary" not in err
        mission_log = (o / "logs" / "mission.log").read_text()
        assert ("radseek mission: search failed" in mission_log) == (failure is not None), mission_log[-2000:]
    a, b = (json.loads((o / "summary.json").read_text()) for o in outs)
    assert a["dwell_points"] == MAX_DWELLS and a["frames_recorded"] > 100
    for key in ("error_m", "dwell_points", "mission_time_s", "flight_time_s", "frames_recorded"):
        assert a[key] == b[key], key
    assert _without_wall(a) == _without_wall(b)
    ma, mb = (json.loads((o / "dataset" / "mission_summary.json").read_text()) for o in outs)
    assert _without_wall(ma) == _without_wall(mb)
    for key in ("radseek/uav0/detector/histogram", "radseek/uav0/pose"):  # sent per simulated tick: the same
        assert ma["samples"][key] == mb["samples"][key], key
    assert ma["frames_lost"] == 0
    fa, fb = ((o / "dataset" / "frames.csv").read_text() for o in outs)
    assert fa == fb
