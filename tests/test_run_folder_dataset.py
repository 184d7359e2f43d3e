"""A `radseek run` output folder given where a dataset is expected: localize, diagnose and replay read the flight
it recorded (its dataset/), and a team run's folder names its per-vehicle datasets (replay takes them jointly)."""

import json
import shutil
from pathlib import Path

import pytest

from radseek.dataset import DatasetError
from radseek_cli import diagnose_cli, localize_cli, replay_cli
from radseek_io.dataset import read_dataset, run_dataset
from radseek_io.truth import read_dataset_with_truth


def _run_folder(root: Path, flight: Path, vehicles: tuple[str, ...] = ()) -> Path:
    """A run's output layout: the operator's scenario.json and summary.json at the top, the flight in dataset/
    (a team's: dataset/<vehicle>/)."""
    root.mkdir()
    shutil.copy(flight / "scenario.json", root / "scenario.json")
    (root / "summary.json").write_text("{}")
    for dest in [root / "dataset" / v for v in vehicles] or [root / "dataset"]:
        shutil.copytree(flight, dest)
    return root


def test_a_run_folder_reads_as_its_dataset(tmp_path, shared_datasets, capsys):
    flight = shared_datasets / "lattice-clean"
    run = _run_folder(tmp_path / "run", flight)
    assert run_dataset(run) == run / "dataset"
    assert run_dataset(flight) == flight  # a dataset names itself
    ds = read_dataset_with_truth(run)
    assert ds.path == run / "dataset" and ds.truth is not None  # truth.json from dataset/, not the run's top
    assert len(ds.frames) == len(read_dataset(flight).frames)

    assert localize_cli.main([str(run), "--method", "sphere", "--json", "--quiet"]) == 0
    from_run = json.loads(capsys.readouterr().out)
    assert localize_cli.main([str(flight), "--method", "sphere", "--json", "--quiet"]) == 0
    from_flight = json.loads(capsys.readouterr().out)
    assert from_run["sources"] == from_flight["sources"]


def test_a_team_run_folder_names_its_vehicles_and_replays_jointly(tmp_path, shared_datasets, capsys):
    flight = shared_datasets / "lattice-clean"
    team = _run_folder(tmp_path / "team", flight, ("uav0", "uav1"))
    with pytest.raises(DatasetError, match=r"uav0, uav1\).*team/dataset/uav0.*replay"):
        read_dataset(team)
    for cli in (localize_cli, diagnose_cli):
        assert cli.main([str(team), "--quiet"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "team/dataset/uav0" in err and "file is missing" not in err

    assert replay_cli.main([str(team), "--method", "sphere", "--json"]) == 0
    out = capsys.readouterr()
    assert "a team's flight: uav0, uav1" in out.err
    rows = json.loads(out.out)
    per_vehicle = len({int(d) for d in read_dataset(flight).frames.dwell if d >= 0})
    assert len(rows) == 2 * per_vehicle  # both vehicles' dwells, one team-wide index each
