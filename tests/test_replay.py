"""radseek replay: the estimate after each dwell of a recorded flight, as the mission had it in the air."""

import json
import math
import shutil
import subprocess
import sys

import numpy as np
import pytest

from detector_fw_sim.scene import load_scene
from estimator.inflight import MIN_SIGMA_M, sigma_m
from radseek_cli.replay_cli import flown_first_dwell, replay
from radseek_cli.replay_cli import main as replay_main
from radseek_io.truth import read_dataset_with_truth
from tests.support.offline_flights import default_flight


def test_replay_reproduces_the_flown_estimates(tmp_path_factory):
    """The brain's in-flight estimates, dwell for dwell, from nothing but the recorded dataset: the same
    frames up to the end of each dwell, pooling, warm start from the previous estimate and wall test."""
    r = default_flight(tmp_path_factory, 3)
    flown = r.brain.estimates
    assert len(flown) >= 2, r.log
    # the mission estimates from the end of exploration on; its mission_log.jsonl records that dwell
    rows = replay(r.dataset, first_dwell=flown[0].dwell)
    assert [row["dwells"] for row in rows] == [e.dwell for e in flown]
    for row, est in zip(rows, flown, strict=True):
        assert row["effects"] == list(est.effects) and row["converged"] == est.converged
        for key in ("x", "y", "cps_at_1m", "background_cps", "sigma_m"):
            assert row[key] == pytest.approx(getattr(est, key), rel=1e-9, abs=1e-12), (row["dwells"], key)


def test_sigma_is_the_xy_semi_major_axis_of_a_trustworthy_estimate():
    cov = np.diag([0.04, 0.09, 0.0, 100.0])  # (x, y, z, cps_at_1m)
    cov[0, 1] = cov[1, 0] = 0.03
    expected = math.sqrt(np.linalg.eigvalsh(cov[:2, :2]).max())
    assert sigma_m(cov) == pytest.approx(expected)
    assert sigma_m(cov[:3, :3].tolist()) == pytest.approx(expected)
    assert sigma_m(cov, converged=False) == math.inf
    assert sigma_m(np.eye(2) * (MIN_SIGMA_M / 2) ** 2) == math.inf  # collapsed: pinned at a bound
    assert sigma_m(np.full((2, 2), np.nan)) == math.inf


def test_replay_cli_starts_where_the_flight_log_says(shared_datasets, tmp_path, capsys):
    ds = tmp_path / "flight"
    shutil.copytree(shared_datasets / "lattice-clean", ds)
    assert flown_first_dwell(ds) is None
    log = [{"t": 1.0, "event": "decision", "phase": "explore", "estimate": None},
           {"t": 2.0, "event": "dwell", "index": 7},
           {"t": 3.0, "event": "decision", "phase": "search", "estimate": {"dwell": 8, "x": 1.0, "y": 2.0}}]
    (ds / "mission_log.jsonl").write_text("".join(json.dumps(e) + "\n" for e in log))
    assert flown_first_dwell(ds) == 8
    capsys.readouterr()
    assert replay_main([str(ds), "--json"]) == 0  # the command in this process (its entry point: the test below)
    rows = json.loads(capsys.readouterr().out)
    assert [r["dwells"] for r in rows] == [8, 9]
    assert all(math.isfinite(r["x"]) and r["sigma_m"] > 0 for r in rows)
    # the in-flight record's tests ride along: one source, no strength order to decide
    assert all(math.isnan(r["strength_order_z"]) and "background_excess_z" in r for r in rows)


def test_replay_converges_on_the_reference_lattice(shared_datasets):
    rows = replay(read_dataset_with_truth(shared_datasets / "lattice-clean"), "mle", {"n_starts": 2})
    assert [r["dwells"] for r in rows] == list(range(1, 10))
    # more dwells, more information: the final ellipse is tighter than after four dwells, and the final
    # error lies within 4 of its own sigmas (plus the ~4 cm per-dwell pose offset of the reference data)
    assert rows[-1]["sigma_m"] < rows[3]["sigma_m"]
    assert rows[-1]["error_m"] < 4 * rows[-1]["sigma_m"] + 0.04


@pytest.mark.io
def test_replay_cli_json_and_bad_input(shared_datasets, tmp_path, capsys):
    out = subprocess.run([sys.executable, "-m", "radseek_cli", "replay", str(shared_datasets / "lattice-clean"),
                          "--method", "sphere", "--json", "--plot", str(tmp_path / "r.png")],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    rows = json.loads(out.stdout)
    assert rows[-1]["dwells"] == 9 and (tmp_path / "r.png").stat().st_size > 1000
    capsys.readouterr()
    assert replay_main([str(tmp_path / "nope")]) == 2  # in this process: the entry point ran above
    assert "not a dataset directory" in capsys.readouterr().err


def test_a_team_run_replays_as_the_teams_flight(tmp_path, capsys):
    """A team run's dataset/ (one folder per vehicle, each with its own dwell indices) replays as one flight:
    every team dwell in time order, on every vehicle's frames up to it; the last estimate within the joint
    fit's own 3 sigma of the truth, as the flown one."""
    from launch.offline_team import fly_team_offline
    from radseek_cli.replay_cli import main as replay_main
    from radseek_io.dataset import write_dataset

    r = fly_team_offline(load_scene(), 2, seed=0)
    f, n = r.dataset.frames, 2
    for v in range(n):  # each vehicle's own dataset, as radseek run --vehicles 2 writes it
        mine = f.select(f.vehicle == v)
        mine.dwell[:] = np.where(mine.dwell >= 0, (mine.dwell - v) // n, -1)
        write_dataset(tmp_path / "dataset" / f"uav{v}", mine, r.dataset.scenario, r.dataset.truth)
    capsys.readouterr()
    assert replay_main([str(tmp_path / "dataset"), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    ends = [row["t"] for row in rows]
    assert ends == sorted(ends) and [row["dwells"] for row in rows] == list(range(1, len(rows) + 1))
    assert len(rows) == len(np.unique(f.dwell[f.dwell >= 0]))
    assert {int(d) % n for d in (row["dwell"] for row in rows)} == {0, 1}  # both vehicles' dwells
    last = rows[-1]
    assert last["error_m"] < 3 * max(last["sigma_m"], MIN_SIGMA_M)
