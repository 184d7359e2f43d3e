"""A team member that recorded nothing (killed before its first frame, flooded) does not cost the team its result:
the report and summary.json are written from the others, the member marked failed with the reason."""

import shutil

from launch.report import write_team_report
from tests.support.team_summary import write_found_summary


def test_a_member_with_no_frames_is_marked_and_the_others_reported(tmp_path, shared_datasets):
    out = tmp_path / "run"
    shutil.copytree(shared_datasets / "lattice-clean", out / "dataset" / "uav0")
    (out / "dataset" / "uav1").mkdir(parents=True)
    shutil.copy(shared_datasets / "lattice-clean" / "scenario.json", out / "dataset" / "uav1")
    header = (shared_datasets / "lattice-clean" / "frames.csv").read_text().splitlines()[0]
    (out / "dataset" / "uav1" / "frames.csv").write_text(header + "\n")  # only a header: no frames
    write_found_summary(out / "dataset" / "uav0")
    summary = write_team_report(out, ["uav0", "uav1"], "uav0")
    rows = {r["vehicle"]: r for r in summary["per_vehicle"]}
    assert not rows["uav0"]["failed"] and rows["uav0"]["dwell_points"] > 0
    assert rows["uav1"]["failed"] and "no frames" in rows["uav1"]["error"]
    assert (out / "summary.json").exists() and (out / "report.png").stat().st_size > 10_000
    assert summary["decided_by"] == "uav0" and summary["error_m"] < 0.5
