"""One simulated world: ``radseek run SCENE --seed S`` (each part its own process over zenoh and MAVLink, with
lockstep) and the in-process driver the campaigns and benchmarks use (``launch.offline.fly_offline``) fly
the same flight: the same frames.csv row for row (times, estimated poses, counts, dwell indices), the same
dwell points, mission time and error. Two scenes, a short honest configuration (3-4 dwells) at 50x, each a run
other tests read too, flown once per test run (flight.mcap recorded: the recorder is one more subscriber and changes
no flight): the default scene's is the first of tests/test_lockstep_repro.py's pair (seed 0, 4 dwells),
lattice-wall's the second of tests/test_run_ports.py's side-by-side pair (seed 1, 3 dwells)."""

import json
import subprocess
import sys

import numpy as np
import pytest

from detector_fw_sim.scene import load_scene
from launch.offline import fly_offline
from mission.search import SearchConfig
from radseek.topics import ESTIMATE_BLOCK
from radseek_io.mcap_frames import read_flight
from tests.support import flooded_team_run as flooded
from tests.support import same_seed_runs as same_seed
from tests.support import side_by_side_runs as side_by_side
from tests.support.flooded_team_run import flooded_team_run
from tests.support.team_frames import assert_frames_csv, assert_same_team_flight

#: the shared runs' own wall bound (each test may wait for another worker's run), and room to compare
pytestmark = [pytest.mark.slow, pytest.mark.io, pytest.mark.timeout(side_by_side.RUN_TIMEOUT_S + 300)]


def _summary(out) -> dict:
    summary = json.loads((out / "dataset" / "mission_summary.json").read_text())
    return {**summary, "error_m": json.loads((out / "summary.json").read_text())["error_m"]}


@pytest.mark.parametrize(("scene", "seed"), [
    (same_seed.SCENE, same_seed.SEED),
    # flown beside test_run_ports' other run while the default ports are held: never beside another test holding them
    pytest.param(*side_by_side.RUNS[1][:2], marks=pytest.mark.exclusive("default-ports-7447-14540"))])
def test_the_stack_and_the_campaigns_fly_the_same_flight(tmp_path_factory, scene, seed):
    if scene == same_seed.SCENE:  # the first of test_lockstep_repro's two runs (recorded, 4 dwells), flown once
        runs, k, dwells = same_seed.same_seed_runs(tmp_path_factory), 0, same_seed.MAX_DWELLS
    else:  # the second of test_run_ports' two side-by-side runs (recorded, 3 dwells), flown once
        runs, k, dwells = side_by_side.side_by_side_on_held_defaults(tmp_path_factory), 1, side_by_side.RUNS[1][2]
    out = runs["outs"][k]
    assert runs["codes"][k] in (0, 3), runs["errs"][k][-3000:]  # 3: searched to the end of the dwell budget
    stack = _summary(out)
    config = SearchConfig(max_dwells=dwells, max_search_dwells=dwells)  # as radseek mission sets them
    r = fly_offline(load_scene(scene), config, seed=seed)
    for key in ("reason", "dwell_points", "search_dwell_points", "mission_time_s", "flight_time_s",
                "frames_recorded", "frames_lost"):
        assert r.summary[key] == stack[key], key
    assert r.summary["estimate"]["x"] == stack["estimate"]["x"] and r.summary["outcome"] == stack["outcome"]
    assert r.error_m == pytest.approx(stack["error_m"], abs=1e-9)
    rows = assert_frames_csv(out / "dataset" / "frames.csv", r.dataset.frames)
    assert [int(row["dwell"]) for row in rows] == [int(d) for d in r.dataset.frames.dwell]
    # the last estimate the mission published (flight.mcap) carries the covariance its search decided on: the
    # in-process flight's final record's, number for number
    last = read_flight(out / "flight.mcap").estimates[-1]
    block = np.array(last.covariance[:ESTIMATE_BLOCK]).reshape(4, 4)
    np.testing.assert_array_equal(block[:3, :3], np.array(r.brain.estimator.estimate["covariance"]))


def test_a_team_flies_the_same_flight_through_the_stack_and_in_process(tmp_path_factory):
    """``radseek run --vehicles 2`` (four processes taking their frames in turn over zenoh) and
    ``launch.offline_team.fly_team_offline`` (two executives in one process): each vehicle's frames.csv row for
    row, and the same joint estimate. The run is test_team_flood's (default scene, seed 3, flown once per test run),
    flooded and forged while it flew: test_team_flood holds that the flood changes nothing of it."""
    run = flooded_team_run(tmp_path_factory)
    assert run["code"] in (0, 3), run["stderr"][-3000:]
    stack = json.loads((run["out"] / "summary.json").read_text())
    assert_same_team_flight(run["out"], stack, flooded.SCENE, flooded.SEED, tmp_path_factory=tmp_path_factory)


# never beside test_run_flood_summary's 100x flood: a stack beside it starves the mission past the board's copies
@pytest.mark.exclusive("default-ports-7447-14540")
def test_a_check_dwell_flies_the_same_through_the_stack(tmp_path):
    """Two-source, information planner, seed 0: the one-source estimate's background stands above the operator's,
    so the mission flies a check dwell before it stops (mission/search.py ``_check_excess``). Through the stack
    (its own run, 50x, every port free) the check is decided in the mission process, and the flight is the
    in-process driver's row for row: the same frames, the check, the second source and the error."""
    from tests.conftest import free_port
    from vehicle_sim.harness import free_udp_port

    dwells, out = 8, tmp_path / "run"
    cmd = [sys.executable, "-m", "radseek_cli", "run", "two-source", "--strategy", "info", "--out", str(out),
           "--quiet", "--speedup", "50", "--max-dwells", str(dwells), "--seed", "0", "--zenoh-port", str(free_port()),
           "--mavlink-port", str(free_udp_port()), "--gcs-port", str(free_udp_port()),
           "--vehicle-local-ports", f"{free_udp_port()},{free_udp_port()}", "--no-mcap",
           "--timeout", str(side_by_side.RUN_TIMEOUT_S)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=side_by_side.RUN_TIMEOUT_S + 60)
    assert proc.returncode == 0, proc.stderr[-3000:]
    stack = _summary(out)
    r = fly_offline(load_scene("two-source"),
                    SearchConfig(strategy="info", max_dwells=dwells, max_search_dwells=dwells), seed=0)
    assert r.brain.check_dwells == 1
    log = [json.loads(line) for line in (out / "dataset" / "mission_log.jsonl").read_text().splitlines()]
    assert sum(e.get("reason", "").startswith("check:") for e in log if e.get("event") == "decision") == 1
    for key in ("reason", "dwell_points", "search_dwell_points", "mission_time_s", "frames_recorded"):
        assert r.summary[key] == stack[key], key
    assert stack["estimate"]["effects"] == ["second_source"] == r.brain.estimator.estimate["effects"]
    assert r.error_m == pytest.approx(stack["error_m"], abs=1e-9)
    rows = assert_frames_csv(out / "dataset" / "frames.csv", r.dataset.frames)
    assert [int(row["dwell"]) for row in rows] == [int(d) for d in r.dataset.frames.dwell]
