"""Issue 12 probes on the dataset reader and geometry: no silent wrong answer, no traceback, no lost flight.

Each test is one probe from the issue: it failed (wrong value accepted, traceback, or whole flight refused)
on the reader before the fix. Errors must be ``DatasetError`` naming the file and the row/column or key.
"""

from __future__ import annotations

import csv
import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from radseek.dataset import DatasetError, Wall
from radseek.frame_record import CHANNEL_COLUMNS, COLUMNS, COUNT_DTYPE
from radseek.geometry import path_lengths, segment_hits_walls
from radseek_io import dataset
from radseek_io.dataset import read_dataset, read_frames
from radseek_io.truth import read_dataset_with_truth
from tests.conftest import shared_dataset_names

BASE = "lattice-clean"


def _copy(shared: Path, tmp: Path, name: str = BASE) -> Path:
    dst = tmp / f"ds-{name}"
    shutil.copytree(shared / name, dst)
    for p in dst.iterdir():
        p.chmod(0o644)
    return dst


def _edit_scenario(path: Path, edit) -> Path:
    d = json.loads((path / "scenario.json").read_text())
    edit(d)
    (path / "scenario.json").write_text(json.dumps(d))
    return path


def _edit_cell(path: Path, line: int, column: str, value: str) -> Path:
    lines = (path / "frames.csv").read_text().splitlines()
    header = lines[0].split(",")
    row = lines[line - 1].split(",")
    row[header.index(column)] = value
    lines[line - 1] = ",".join(row)
    (path / "frames.csv").write_text("\n".join(lines) + "\n")
    return path


# ------------------------------------------------------------------ silent wrong answers


def test_fractional_count_is_refused_not_truncated(shared_datasets, tmp_path):
    path = _edit_cell(_copy(shared_datasets, tmp_path), 5, "c03", "2.5")
    with pytest.raises(DatasetError, match=r"frames.csv: row 5, column 'c03': counts must be integers"):
        read_dataset(path)


def test_fractional_dwell_is_refused_not_truncated(shared_datasets, tmp_path):
    path = _edit_cell(_copy(shared_datasets, tmp_path), 7, "dwell", "2.7")
    with pytest.raises(DatasetError, match=r"frames.csv: row 7, column 'dwell': must be an integer"):
        read_dataset(path)


def test_whole_numbers_written_as_floats_are_still_counts(shared_datasets, tmp_path):
    # another generator may write "3.0": that is a count of 3, and dwell "2.0" is dwell 2
    path = _copy(shared_datasets, tmp_path)
    ref = read_dataset(path).frames
    _edit_cell(path, 5, "c03", f"{int(ref.counts[3, 3])}.0")
    _edit_cell(path, 5, "dwell", f"{int(ref.dwell[3])}.0")
    got = read_dataset(path).frames
    assert got.counts.dtype == COUNT_DTYPE
    assert np.array_equal(got.counts, ref.counts) and np.array_equal(got.dwell, ref.dwell)


@pytest.mark.parametrize("fmt", ["radseek-dataset/10", "radseek-dataset/2", "radseek-dataset/1x", 1, None])
def test_other_format_versions_are_refused(shared_datasets, tmp_path, fmt):
    path = _edit_scenario(_copy(shared_datasets, tmp_path), lambda d: d.update(format=fmt))
    with pytest.raises(DatasetError, match=r"scenario.json: key 'format' is"):
        read_dataset(path)


def test_minor_revision_of_version_1_is_read(shared_datasets, tmp_path):
    path = _edit_scenario(_copy(shared_datasets, tmp_path), lambda d: d.update(format="radseek-dataset/1.1"))
    assert len(read_dataset(path).frames) > 0


@pytest.mark.parametrize(
    ("edit", "key"),
    [
        (lambda d: d["bounds"]["min"].__setitem__(0, float("nan")), r"bounds.min\[0\]"),
        (lambda d: d["bounds"]["max"].__setitem__(2, float("inf")), r"bounds.max\[2\]"),
        (lambda d: d.update(source_z=float("nan")), "source_z"),
        (lambda d: d.update(walls=[{"start": [float("nan"), 0], "end": [1, 1], "thickness": 0.2}]),
         r"walls\[0\].start\[0\]"),
        (lambda d: d.update(walls=[{"start": [0, 0], "end": [1, 1], "thickness": float("nan")}]),
         r"walls\[0\].thickness"),
        (lambda d: d["detector"]["channel_edges_keV"].__setitem__(3, float("nan")),
         r"detector.channel_edges_keV\[3\]"),
    ],
)
def test_non_finite_scenario_numbers_are_refused(shared_datasets, tmp_path, edit, key):
    path = _edit_scenario(_copy(shared_datasets, tmp_path), edit)
    with pytest.raises(DatasetError, match=rf"scenario.json: key '{key}' must be finite"):
        read_dataset(path)


def test_zero_length_wall_is_not_an_infinite_wall():
    # a point "wall" 7 m away used to put 1.8 m of concrete on a path that never comes near it
    point = [Wall((7.0, 0.0), (7.0, 0.0), 0.2, 3.0)]
    a, b = np.array([0.0, 0.0, 1.8]), np.array([0.0, 5.0, 0.0])
    assert path_lengths(a, b, point) == 0.0
    assert not segment_hits_walls(a, b, point, inflate=0.5)
    # a real wall is still crossed
    wall = [Wall((7.0, -1.0), (7.0, 1.0), 0.2, 3.0)]
    assert path_lengths(np.array([6.0, 0.0, 1.0]), np.array([8.0, 0.0, 1.0]), wall) == pytest.approx(0.2)


def test_zero_length_wall_in_scenario_is_an_error(shared_datasets, tmp_path):
    path = _edit_scenario(_copy(shared_datasets, tmp_path),
                          lambda d: d.update(walls=[{"start": [7, 0], "end": [7, 0], "thickness": 0.2}]))
    with pytest.raises(DatasetError, match=r"scenario.json: walls\[0\]: .*zero-length wall"):
        read_dataset(path)


@pytest.mark.parametrize("lo,hi", [(-1e6, 1e6), (0.0, 5000.0), (2e4, 2e4 + 10)])
def test_unbounded_search_area_is_an_error(shared_datasets, tmp_path, lo, hi):
    path = _edit_scenario(_copy(shared_datasets, tmp_path),
                          lambda d: d["bounds"].update(min=[lo, 0, 0], max=[hi, 8, 0.5]))
    with pytest.raises(DatasetError, match=r"scenario.json: key 'bounds"):
        read_dataset(path)


# ------------------------------------------------------------------ errors instead of tracebacks


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: d.update(source_z="zero"), r"key 'source_z' must be a number, got 'zero'"),
        (lambda d: d.update(source_z=True), r"key 'source_z' must be a number"),
        (lambda d: d["bounds"].update(min=[0, "a", 0]), r"key 'bounds.min\[1\]' must be a number"),
        (lambda d: d["detector"]["channel_edges_keV"].__setitem__(0, "40"), r"channel_edges_keV\[0\]' must be"),
        (lambda d: d.update(walls=5), r"key 'walls' must be a list"),
        (lambda d: d.update(walls=[{"start": 3, "end": [1, 1], "thickness": 0.2}]), r"walls\[0\].start' must be"),
        (lambda d: d.update(detector=[1, 2]), r"key 'detector' must be an object"),
        (lambda d: d["detector"].update(axis=3), r"key 'detector.axis' must be a string"),
    ],
)
def test_bad_scenario_types_name_the_key(shared_datasets, tmp_path, edit, match):
    path = _edit_scenario(_copy(shared_datasets, tmp_path), edit)
    with pytest.raises(DatasetError, match="scenario.json: .*" + match):
        read_dataset(path)


@pytest.mark.parametrize(
    ("content", "match"),
    [
        ("[]", "must hold a JSON object, got list"),
        ('{"sources": {"x": 1}}', "key 'sources' must be a list"),
        ('{"sources": [3]}', r"sources\[0\] must be an object"),
        ('{"sources": [{"x": "a", "y": 1, "cps_at_1m": 5}]}', r"key 'sources\[0\].x' must be a number"),
        ('{"sources": [{"x": 1, "y": 1}]}', r"sources\[0\]: missing key 'cps_at_1m'"),
        ('{"sources": [], "effects": {"dead_time": 3}}', r"key 'effects.dead_time' must be an object"),
        ('{"sources": [{"x": 1, "y": 1, "cps_at_1m": 5}], "effects": {"second_source": {"x": 1}}}',
         r"effects.second_source': missing parameter 'y'"),
        ('{"sources": [], "effects": {"dead_time": {"tau_s": "fast"}}}', r"effects.dead_time.tau_s' must be"),
        ('{"sources": [], "background_cps": NaN}', r"key 'background_cps' must be finite"),
        ("\xff\xfe not utf-8", "not UTF-8"),
        ("[" * 100_000, "not valid JSON"),
    ],
)
def test_bad_truth_names_the_key(shared_datasets, tmp_path, content, match):
    path = _copy(shared_datasets, tmp_path)
    (path / "truth.json").write_bytes(content.encode("latin-1"))
    with pytest.raises(DatasetError, match="truth.json: .*" + match):
        read_dataset_with_truth(path)
    assert read_dataset(path).truth is None  # the frames and scenario alone never open truth.json


def test_utf8_bom_header_is_read(shared_datasets, tmp_path):
    path = _copy(shared_datasets, tmp_path)
    ref = read_dataset(path).frames
    text = (path / "frames.csv").read_text()
    (path / "frames.csv").write_text("\ufeff" + text, encoding="utf-8")
    (path / "scenario.json").write_text("\ufeff" + (path / "scenario.json").read_text(), encoding="utf-8")
    got = read_dataset(path).frames
    assert np.array_equal(got.counts, ref.counts) and np.array_equal(got.t, ref.t)


def test_truncated_last_row_is_skipped_with_a_warning(shared_datasets, tmp_path):
    path = _copy(shared_datasets, tmp_path)
    ref = read_dataset(path).frames
    text = (path / "frames.csv").read_text().rstrip("\n")
    n_lines = text.count("\n") + 1
    (path / "frames.csv").write_text(text[:-37])  # a recorder killed mid-row: no newline, fewer fields
    with pytest.warns(dataset.DatasetWarning, match=rf"row {n_lines}: \d+ fields, header has 42 \(truncated last row"):
        got = read_dataset(path).frames
    assert len(got) == len(ref) - 1
    assert np.array_equal(got.counts, ref.counts[:-1])
    with pytest.raises(DatasetError, match=rf"row {n_lines}: .*truncated last row"):
        read_dataset(path, truncated_last_row="error")


def test_truncated_row_followed_by_rows_is_still_an_error(shared_datasets, tmp_path):
    path = _copy(shared_datasets, tmp_path)
    lines = (path / "frames.csv").read_text().splitlines()
    lines[9] = lines[9][:30]
    (path / "frames.csv").write_text("\n".join(lines) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(DatasetError, match=r"row 10: \d+ fields, header has 42 \(truncated row"):
            read_dataset(path)


def test_row_with_more_fields_than_the_header_is_an_error(shared_datasets, tmp_path):
    path = _copy(shared_datasets, tmp_path)
    lines = (path / "frames.csv").read_text().splitlines()
    lines[4] += ",7"
    (path / "frames.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=r"row 5: 43 fields, header has 42"):
        read_dataset(path)


@pytest.mark.parametrize(("cell", "what"), [("abc", "is not a number"), ("", "is not a number"),
                                            ("nan", "is not finite"), ("1e400", "is not finite")])
def test_bad_cells_name_row_and_column(shared_datasets, tmp_path, cell, what):
    path = _edit_cell(_copy(shared_datasets, tmp_path), 12, "y", cell)
    with pytest.raises(DatasetError, match=rf"frames.csv: row 12, column 'y': .*{what}"):
        read_dataset(path)


def test_row_numbers_count_blank_lines(shared_datasets, tmp_path):
    path = _copy(shared_datasets, tmp_path)
    lines = (path / "frames.csv").read_text().splitlines()
    lines[3:3] = ["", "   ", ",,,"]
    (path / "frames.csv").write_text("\n".join(lines) + "\n")
    assert len(read_dataset(path).frames) == len(lines) - 4  # header and three blank lines
    _edit_cell(path, 9, "duration", "-0.1")
    with pytest.raises(DatasetError, match=r"row 9, column 'duration': must be > 0"):
        read_dataset(path)


def test_huge_count_is_refused(shared_datasets, tmp_path):
    path = _edit_cell(_copy(shared_datasets, tmp_path), 3, "c00", "100000000000000000000")
    with pytest.raises(DatasetError, match=r"row 3, column 'c00': counts must be <="):
        read_dataset(path)


# ------------------------------------------------------------------ other generators' files


def _reference_parse(file: Path) -> dict[str, np.ndarray]:
    """An independent, obviously correct parse of a well-formed frames.csv (csv module, by column name)."""
    with open(file, newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if any(v.strip() for v in r.values() if v)]
    cols = {c: np.array([float(r[c]) for r in rows]) for c in COLUMNS}
    return cols


@pytest.mark.parametrize("name", shared_dataset_names())
def test_shared_datasets_read_exactly(shared_datasets, name):
    ref = _reference_parse(shared_datasets / name / "frames.csv")
    f = read_dataset(shared_datasets / name).frames
    for c in COLUMNS[:10]:
        assert np.array_equal(getattr(f, c), ref[c]), c
    assert f.dwell.dtype.kind == "i" and f.counts.dtype == COUNT_DTYPE
    assert np.array_equal(f.counts, np.column_stack([ref[c] for c in CHANNEL_COLUMNS]))


def test_extra_columns_quotes_crlf_and_column_order_are_accepted(shared_datasets, tmp_path):
    path = _copy(shared_datasets, tmp_path)
    ref = read_dataset(path).frames
    with open(path / "frames.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    header = rows[0]
    order = list(reversed(range(len(header))))
    with open(path / "frames.csv", "w", newline="") as fh:
        w = csv.writer(fh, quoting=csv.QUOTE_ALL, lineterminator="\r\n")
        w.writerow(["note", *[header[i] for i in order], "seq"])
        for k, r in enumerate(rows[1:]):
            w.writerow([f"free text, {k}", *[r[i] for i in order], str(k)])
    got = read_dataset(path).frames
    assert np.array_equal(got.counts, ref.counts) and np.array_equal(got.yaw, ref.yaw)


# ------------------------------------------------------------------ progress


def test_progress_callback_reports_rows(shared_datasets, capsys):
    seen: list[tuple[int, int]] = []
    f = read_frames(shared_datasets / BASE / "frames.csv", progress=lambda done, total: seen.append((done, total)))
    assert seen and seen[-1][0] == len(f) and all(total >= len(f) for _, total in seen)
    cb = dataset.stderr_progress("reading", min_interval_s=0.0, after_s=0.0)
    read_frames(shared_datasets / BASE / "frames.csv", progress=cb)
    assert f"reading: 100 % ({len(f)} rows)" in capsys.readouterr().err
