"""A team run counts each vehicle's dwells one way everywhere: the ended ones, in its mission_summary.json, the
team's summary.json and the report's legend; a dwell begun but not ended when the search stopped (in frames.csv,
drawn hollow) is named as such, not counted (issue 35: the report said "uav1: 2 dwells" and drew three, and
uav1's mission_summary.json said 4, the joint count it knew of; its search dwells likewise)."""

import json
import shutil
from types import SimpleNamespace

import numpy as np

from launch.report import write_team_report
from mission.team_link import TeamLinkBase
from radseek.dataset import Frames
from radseek_io.dataset import read_dataset
from tests.support.team_summary import write_found_summary


def test_the_report_counts_ended_dwells_and_names_the_unfinished(tmp_path, shared_datasets):
    flight = shared_datasets / "lattice-clean"
    begun = len({int(d) for d in read_dataset(flight).frames.dwell if d >= 0})
    out = tmp_path / "run"
    for name, ended in (("uav0", begun), ("uav1", 2)):  # uav1 stopped in its third dwell
        shutil.copytree(flight, out / "dataset" / name)
        log = [{"event": "dwell", "t": float(k)} for k in range(ended)] + [{"event": "done", "t": 99.0}]
        (out / "dataset" / name / "mission_log.jsonl").write_text("".join(json.dumps(e) + "\n" for e in log))
    write_found_summary(out / "dataset" / "uav0")
    summary = write_team_report(out, ["uav0", "uav1"], "uav0")
    rows = {r["vehicle"]: r for r in summary["per_vehicle"]}
    assert rows["uav1"]["dwell_points"] == 2 and rows["uav1"]["dwells_not_ended"] == begun - 2
    assert rows["uav0"]["dwell_points"] == begun and rows["uav0"]["dwells_not_ended"] == 0
    assert summary["dwell_points"] == begun + 2


def test_a_members_mission_summary_counts_its_own_ended_dwells():
    link = TeamLinkBase("uav1", ("uav0", "uav1"))
    for k in range(2):
        link.add_dwell(k, np.array([1.0 + k, 2.0, 1.5]), 40.0, 10.0 * k, 10.0 * k + 5, np.zeros((0, 3)))
    z = np.zeros(3)
    own = Frames(t=np.array([0.1, 0.2, 0.3]), duration=z + 0.1, x=np.array([0.0, 1.0, 1.0]),
                 y=np.array([0.0, 0.0, 1.0]), z=z + 1.5, yaw=z, var_x=z, var_y=z, var_z=z, dwell=np.array([-1, -1, 0]),
                 counts=np.zeros((3, 32), dtype=int))
    # the joint history it knew: its 2 and uav0's 2, of which uav0's second and its own second were search dwells
    brain = SimpleNamespace(history=[object()] * 4, search_dwells=2, search_dwelled_by=[0, 1])
    s = link.summary(brain, own)
    assert s["dwell_points"] == s["own_dwell_points"] == 2 and s["team_dwell_points"] == 4
    assert s["search_dwell_points"] == 1 and s["team_search_dwell_points"] == 2
    assert s["distance_m"] == 1.0  # moving frames only: the step into the dwell is not counted
