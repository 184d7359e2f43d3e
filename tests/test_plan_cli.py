"""``radseek plan``: map from a scenario or scene, plan printed as the topic payload, plots written."""

import json

import numpy as np
import pytest

from planner.occupancy import OccupancyMap
from radseek.dataset import Scenario, Wall
from radseek.topics import Plan
from radseek_cli import plan_cli
from radseek_io.dataset import read_scenario, write_json


@pytest.fixture()
def dataset(tmp_path):
    scenario = Scenario(
        channel_edges_keV=np.linspace(30, 3000, 33), background_cps=25.0, source_z=0.0,
        bounds_min=np.zeros(3), bounds_max=np.array([8.0, 6.0, 0.5]),
        walls=(Wall((4.0, 0.0), (4.0, 4.0), 0.2, 3.0),),
    )
    write_json(tmp_path / "scenario.json", scenario.to_dict())
    return tmp_path


def test_next_best_from_a_dataset_prints_a_valid_plan_payload(dataset, capsys, tmp_path):
    png = tmp_path / "plan.png"
    rc = plan_cli.main(["--dataset", str(dataset), "--source", "6,2,0", "--cps", "2000", "--start", "1,1,1.5,0",
                        "--dwell", "1,1,1.5,40", "--dwell", "2,3,1.5,60", "--dwell", "3,1,1.5,80",
                        "--json", "--plot", str(png)])
    assert rc == 0
    msg = Plan.from_dict(json.loads(capsys.readouterr().out))
    occ = OccupancyMap.from_scenario(read_scenario(dataset / "scenario.json"), 0.3)
    path = np.array(msg.points("path"))
    assert len(msg.points("dwell_points")) == 1 and np.allclose(path[0], [1, 1, 1.5, 0])
    assert np.all(occ.segments_valid(path[:-1, :3], path[1:, :3]))
    assert png.stat().st_size > 10_000


@pytest.mark.parametrize("method", ["explore", "lattice", "lawnmower", "spiral", "greedy"])
def test_every_method_plans(dataset, capsys, method):
    rc = plan_cli.main(["--dataset", str(dataset), "--method", method, "--source", "6,2,0", "--start", "1,1,1.5,0"])
    out = capsys.readouterr().out
    assert rc == 0 and "dwell 0:" in out


def test_bad_start_and_missing_belief_are_reported(dataset, capsys):
    assert plan_cli.main(["--dataset", str(dataset), "--start", "4,1,1.5,0", "--source", "6,2,0"]) == 2
    assert plan_cli.main(["--dataset", str(dataset), "--start", "1,1,1.5,0", "--method", "next-best"]) == 2
    assert "needs --source" in capsys.readouterr().err
    # with no method and no belief it explores (so `radseek plan` runs with no arguments), and says so
    assert plan_cli.main(["--dataset", str(dataset), "--start", "1,1,1.5,0"]) in (0, 1)
    assert "planning an exploration" in capsys.readouterr().err


def test_fig4_replica_is_written(tmp_path):
    png = tmp_path / "fig4.png"
    assert plan_cli.main(["--fig4", str(png)]) == 0
    assert png.stat().st_size > 20_000
