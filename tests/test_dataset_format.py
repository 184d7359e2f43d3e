import shutil

import numpy as np
import pytest

from radseek.dataset import DatasetError
from radseek_io.dataset import write_dataset
from radseek_io.truth import read_dataset_with_truth
from tests.conftest import shared_dataset_names


@pytest.mark.parametrize("name", shared_dataset_names())
def test_reads_every_shared_dataset(shared_datasets, name):
    ds = read_dataset_with_truth(shared_datasets / name)
    assert len(ds.frames) > 100
    assert ds.frames.counts.shape == (len(ds.frames), 32)
    assert ds.scenario.channel_edges_keV.shape == (33,)
    assert ds.truth is not None and len(ds.truth.sources) >= 1
    assert np.all(np.diff(ds.frames.t) >= 0)


def test_round_trip_keeps_every_value(shared_datasets, tmp_path):
    ds = read_dataset_with_truth(shared_datasets / "lattice-wall")
    write_dataset(tmp_path / "copy", ds.frames, ds.scenario, ds.truth)
    back = read_dataset_with_truth(tmp_path / "copy")
    assert np.array_equal(back.frames.counts, ds.frames.counts)
    assert np.allclose(back.frames.positions, ds.frames.positions, atol=1e-4)
    assert np.allclose(back.frames.pose_variances, ds.frames.pose_variances, rtol=1e-3)
    assert back.scenario.walls == ds.scenario.walls
    assert back.truth == ds.truth


def _corrupt(shared_datasets, tmp_path, edit):
    dst = tmp_path / "bad"
    shutil.copytree(shared_datasets / "lattice-clean", dst)
    lines = (dst / "frames.csv").read_text().splitlines()
    edit(lines)
    (dst / "frames.csv").write_text("\n".join(lines) + "\n")
    return dst


def test_negative_counts_name_row_and_column(shared_datasets, tmp_path):
    def edit(lines):
        cells = lines[5].split(",")
        cells[10] = "-3"
        lines[5] = ",".join(cells)

    with pytest.raises(DatasetError, match=r"frames.csv: row 6, column 'c00'"):
        read_dataset_with_truth(_corrupt(shared_datasets, tmp_path, edit))


def test_nan_pose_is_rejected(shared_datasets, tmp_path):
    def edit(lines):
        cells = lines[3].split(",")
        cells[2] = "nan"
        lines[3] = ",".join(cells)

    with pytest.raises(DatasetError, match=r"row 4, column 'x'"):
        read_dataset_with_truth(_corrupt(shared_datasets, tmp_path, edit))


def test_truncated_row_and_missing_column(shared_datasets, tmp_path):
    with pytest.raises(DatasetError, match="truncated"):
        read_dataset_with_truth(_corrupt(shared_datasets, tmp_path, lambda ls: ls.__setitem__(7, ls[7][:20])))
    def rename(lines):
        lines[0] = lines[0].replace("var_x", "vx")

    with pytest.raises(DatasetError, match="lacks column"):
        read_dataset_with_truth(_corrupt(shared_datasets, tmp_path / "b", rename))


def test_bad_scenario_names_the_key(shared_datasets, tmp_path):
    dst = tmp_path / "bad"
    shutil.copytree(shared_datasets / "lattice-clean", dst)
    text = (dst / "scenario.json").read_text().replace('"background_cps": 30.5', '"background_cps": "lots"')
    (dst / "scenario.json").write_text(text)
    with pytest.raises(DatasetError, match=r"scenario.json: key 'background_cps' must be a number"):
        read_dataset_with_truth(dst)


@pytest.mark.parametrize("value, match", [("-0.01", r"key 'air_mu_per_m' must be in \[0, 1\]"),
                                          ("5", r"key 'air_mu_per_m' must be in \[0, 1\]"),
                                          ('"thin"', r"key 'air_mu_per_m' must be a number")])
def test_bad_air_coefficient_names_the_key(shared_datasets, tmp_path, value, match):
    import json

    dst = tmp_path / "bad"
    shutil.copytree(shared_datasets / "lattice-clean", dst)
    text = (dst / "scenario.json").read_text()
    (dst / "scenario.json").write_text(text.rstrip().rstrip("}") + f', "air_mu_per_m": {value}}}')
    json.loads((dst / "scenario.json").read_text())  # the file itself is valid JSON
    with pytest.raises(DatasetError, match=match):
        read_dataset_with_truth(dst)


def test_air_coefficient_round_trips_and_is_absent_by_default(shared_datasets, tmp_path):
    import dataclasses

    ds = read_dataset_with_truth(shared_datasets / "outdoor-air")
    assert ds.scenario.air_mu_per_m == 0.0 and "air_mu_per_m" not in ds.scenario.to_dict()
    write_dataset(tmp_path / "air", ds.frames, dataclasses.replace(ds.scenario, air_mu_per_m=0.0093), ds.truth)
    back = read_dataset_with_truth(tmp_path / "air")
    assert back.scenario.air_mu_per_m == 0.0093 and "air_mu_per_m" not in back.scenario.extra


def test_a_team_runs_dataset_folder_names_its_vehicles(tmp_path, shared_datasets):
    """``OUT/dataset`` of a team run holds uav0/, uav1/: the error names them instead of a missing scenario.json."""
    for v in ("uav0", "uav1"):
        shutil.copytree(shared_datasets / "lattice-clean", tmp_path / v)
    with pytest.raises(DatasetError, match=r"uav0, uav1.*give one of them, e.g. .*uav0"):
        read_dataset_with_truth(tmp_path)
    assert len(read_dataset_with_truth(tmp_path / "uav1").frames) > 0


def test_a_duplicated_frame_is_named_by_row(tmp_path, shared_datasets, capsys):
    """One row repeated (a recorder that wrote a frame twice) was counted five more times by localize."""
    shutil.copy(shared_datasets / "lattice-clean" / "scenario.json", tmp_path)
    lines = (shared_datasets / "lattice-clean" / "frames.csv").read_text().splitlines()
    (tmp_path / "frames.csv").write_text("\n".join(lines[:11] + [lines[10]] * 5 + lines[11:]) + "\n")
    with pytest.raises(DatasetError, match=r"frames.csv: row 12, column 't': repeats the previous row's time"):
        read_dataset_with_truth(tmp_path)
    from radseek_cli.localize_cli import main as localize_main

    assert localize_main([str(tmp_path), "--method", "sphere"]) == 2  # the command, as the probe ran it
    assert capsys.readouterr().err == (f"radseek localize: {tmp_path}/frames.csv: row 12, column 't': repeats the "
                                       "previous row's time (a duplicated frame)\n")
