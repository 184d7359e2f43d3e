"""Issue 34's flood and forgery probe on a whole team run: while `radseek run --vehicles 2` flies, a local process
floods and forges the stack's keys (junk and forged histograms, sim clocks of 1e9 and -5 s, a forged team estimate,
mission/lockstep), once without credentials and once with the run's observer credentials (a reader's). The run
keeps its result: summary.json with both vehicles' results, and the very flight an unflooded team flies (the
in-process team of `launch.offline_team`, frame for frame: lockstep makes the flight independent of timing).
The run is flown once per test run (tests/support/flooded_team_run.py): test_one_world reads it too.
"""

from __future__ import annotations

import json

import pytest

from tests.support.flooded_team_run import RUN_TIMEOUT_S, SCENE, SEED, flooded_team_run
from tests.support.team_frames import assert_same_team_flight


@pytest.mark.slow
@pytest.mark.io
@pytest.mark.timeout(RUN_TIMEOUT_S + 300)
def test_a_flooded_and_forged_team_run_keeps_its_result_and_its_flight(tmp_path_factory):
    run = flooded_team_run(tmp_path_factory)
    out, stderr = run["out"], run["stderr"]
    assert run["refused"]  # an outsider cannot speak at all
    assert run["code"] in (0, 3), stderr[-3000:]  # 3: searched to the end of the dwell budget; 4 would be a loss
    assert run["sent"] > 1000, run["sent"]  # the flood went on while the team flew
    summary = json.loads((out / "summary.json").read_text())
    rows = {r["vehicle"]: r for r in summary["per_vehicle"]}
    assert set(rows) == {"uav0", "uav1"} and not any(r["failed"] for r in rows.values()), rows
    for name in rows:
        log = (out / "logs" / f"mission-{name}.log").read_text()
        assert "Traceback" not in log, log[-3000:]
    # the flight an unflooded team flies, frame for frame
    assert_same_team_flight(out, summary, SCENE, SEED, tmp_path_factory=tmp_path_factory)
