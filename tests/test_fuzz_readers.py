"""Property-based fuzzing of the readers (issue 12): frames.csv, scenario.json, truth.json and scene files.

Any input gives either a valid object or the module's own error (``DatasetError`` / ``SceneError``) naming
the file and the row, column, key or field; never another exception. Inputs are mutations of valid files
(cells replaced by hostile tokens, keys set to any JSON value or deleted, text truncated or spliced), so
most examples reach deep checks instead of failing at the first byte. Bounded: ``max_examples`` per test,
no deadline (pyarrow's first call and slow CI machines).
"""

from __future__ import annotations

import copy
import json
import math
import tempfile
import tomllib
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from detector_fw_sim.scene import DEFAULT_SCENE, Scene, SceneError, load_scene, validate_scene
from radseek.dataset import DatasetError, Frames, Scenario
from radseek.frame_record import COLUMNS, COUNT_DTYPE
from radseek.truth import Truth
from radseek_io.dataset import read_frames, read_scenario
from radseek_io.truth import read_truth
from tests.conftest import SHARED_DATASETS

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow],
                database=None)
FUZZ_SCENE = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow],
                      database=None)

BASE = SHARED_DATASETS / "lattice-clean"
_FRAMES_LINES = (BASE / "frames.csv").read_text().splitlines()[:30]
_SCENARIO = json.loads((BASE / "scenario.json").read_text())
_TRUTH = json.loads((SHARED_DATASETS / "two-sources" / "truth.json").read_text())
_SCENE = tomllib.loads(DEFAULT_SCENE.read_text())

HOSTILE_CELLS = ["", " ", "nan", "NaN", "inf", "-inf", "abc", "2.5", "-1", "-2", "1e400", "1e20", "0x10", "1_0",
                 '"', '"3"', "3.0", " 7 ", "\ufeff1", "true", "null", "1,2", "9" * 30, "-0", "+5", ".5", "5."]

json_scalars = (st.none() | st.booleans() | st.integers(-(10**20), 10**20) | st.integers(-(10**400), 10**400)
                | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=6)
                | st.sampled_from([0, -1, 1e7, 0.0, -0.0, 1e-300, 2**63, "0", "1.5"]))
json_values = st.recursive(json_scalars, lambda ch: st.lists(ch, max_size=4) | st.dictionaries(
    st.text(max_size=5), ch, max_size=3), max_leaves=6)


def _paths(obj: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix] if prefix else []
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out += _paths(v, (*prefix, i))
    return out


@st.composite
def mutated(draw, base: Any, n_max: int = 3) -> Any:
    """``base`` with up to ``n_max`` keys or items replaced by any JSON value, deleted, or a new key added."""
    obj = copy.deepcopy(base)
    for _ in range(draw(st.integers(0, n_max))):
        paths = _paths(obj)
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = obj
        for p in path[:-1]:
            parent = parent[p]
        action = draw(st.sampled_from(["set", "set", "delete", "add"]))
        if action == "set":
            parent[path[-1]] = draw(json_values)
        elif action == "delete":
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(st.text(max_size=6))] = draw(json_values)
        else:
            parent.append(draw(json_values))
    return obj


@st.composite
def text_damage(draw, text: str) -> str:
    """Text truncated, with bytes spliced in or a piece deleted (a damaged file), or unchanged."""
    kind = draw(st.sampled_from(["none", "truncate", "insert", "delete"]))
    if kind == "none" or not text:
        return text
    i = draw(st.integers(0, len(text)))
    if kind == "truncate":
        return text[:i]
    if kind == "insert":
        return text[:i] + draw(st.text(max_size=8)) + text[i:]
    return text[:i] + text[i + draw(st.integers(1, 20)):]


def _names_file(exc: Exception, file: Path) -> None:
    assert str(file) in str(exc), exc


# ------------------------------------------------------------------ frames.csv


@st.composite
def frames_csv(draw) -> tuple[str, bool]:
    """A frames.csv text and whether it is unmodified (then it must read exactly)."""
    lines = list(draw(st.sampled_from([_FRAMES_LINES[:2], _FRAMES_LINES[:8], _FRAMES_LINES])))
    rows = [ln.split(",") for ln in lines]
    clean = True
    for _ in range(draw(st.integers(0, 4))):
        r = draw(st.integers(0, len(rows) - 1))
        action = draw(st.sampled_from(["cell", "cell", "drop_cell", "add_cell", "blank", "header"]))
        clean = False
        if not rows[r] and action in ("cell", "drop_cell"):
            action = "add_cell"  # an earlier drop emptied the row
        if not rows[0] and action == "header":
            action = "add_cell"
        if action == "cell":
            c = draw(st.integers(0, len(rows[r]) - 1))
            rows[r][c] = draw(st.sampled_from(HOSTILE_CELLS) | st.text(max_size=5))
        elif action == "drop_cell":
            rows[r].pop(draw(st.integers(0, len(rows[r]) - 1)))
        elif action == "add_cell":
            rows[r].append(draw(st.sampled_from(HOSTILE_CELLS)))
        elif action == "blank":
            rows.insert(r + 1, [draw(st.sampled_from(["", " ", ",,"]))])
        else:
            rows[0][draw(st.integers(0, len(rows[0]) - 1))] = draw(st.sampled_from(["x", "t", "c00", " t", "dwell"]))
    eol = draw(st.sampled_from(["\n", "\r\n"]))
    text = eol.join(",".join(r) for r in rows) + draw(st.sampled_from([eol, ""]))
    if draw(st.booleans()):
        text = "\ufeff" + text
    damaged = draw(text_damage(text))
    return damaged, clean and damaged == text


def _check_frames(f: Frames) -> None:
    n = len(f)
    assert n > 0
    for c in COLUMNS[:10]:
        v = getattr(f, c)
        assert v.shape == (n,) and np.all(np.isfinite(v)), c
    assert f.counts.shape == (n, 32) and f.counts.dtype == COUNT_DTYPE and np.all(f.counts >= 0)
    assert f.dwell.dtype.kind == "i" and np.all(f.dwell >= -1)
    assert np.all(f.duration > 0) and np.all(np.diff(f.t) >= 0)


@FUZZ
@given(frames_csv(), st.sampled_from(["skip", "error"]))
def test_fuzz_frames_csv(case, policy):
    text, clean = case
    with tempfile.TemporaryDirectory() as d:
        file = Path(d) / "frames.csv"
        file.write_bytes(text.encode("utf-8", errors="surrogatepass"))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                f = read_frames(file, truncated_last_row=policy)
            except DatasetError as exc:
                _names_file(exc, file)
                assert not clean or len(_FRAMES_LINES) and "no frames" in str(exc), exc
                assert any(w in str(exc) for w in ("row", "header", "empty", "no frames")), exc
                return
    _check_frames(f)
    if clean:
        rows = np.array([[float(v) for v in ln.split(",")] for ln in text.lstrip("\ufeff").splitlines()[1:]])
        assert np.array_equal(f.t, rows[:, 0]) and np.array_equal(f.counts, rows[:, 10:].astype(np.int64))


@pytest.mark.filterwarnings("ignore::radseek_io.dataset.DatasetWarning")
@FUZZ
@given(st.binary(max_size=400))
def test_fuzz_frames_csv_arbitrary_bytes(data):
    with tempfile.TemporaryDirectory() as d:
        file = Path(d) / "frames.csv"
        file.write_bytes(",".join(COLUMNS).encode() + b"\n" + data)
        try:
            _check_frames(read_frames(file))
        except DatasetError as exc:
            _names_file(exc, file)


# ------------------------------------------------------------------ scenario.json and truth.json


def _dump(obj: Any) -> str:
    try:
        return json.dumps(obj)
    except ValueError:  # an integer too long for str(): write it by hand as a float-ish literal
        return json.dumps(obj, default=str).replace("Infinity", "1e999")


@FUZZ
@given(mutated(_SCENARIO), st.booleans())
def test_fuzz_scenario_json(obj, damage):
    text = _dump(obj)
    with tempfile.TemporaryDirectory() as d:
        file = Path(d) / "scenario.json"
        file.write_text(text[: len(text) // 2] if damage else text)
        try:
            s = read_scenario(file)
        except DatasetError as exc:
            _names_file(exc, file)
            return
    assert isinstance(s, Scenario)
    for arr in (s.channel_edges_keV, s.bounds_min, s.bounds_max):
        assert arr.dtype == float and np.all(np.isfinite(arr))
    assert math.isfinite(s.source_z) and math.isfinite(s.background_cps) and s.background_cps >= 0
    assert np.all(np.diff(s.channel_edges_keV) > 0) and np.all(s.bounds_max >= s.bounds_min)
    for w in s.walls:
        assert w.start != w.end and w.thickness > 0 and w.height > 0
        assert all(math.isfinite(v) for v in (*w.start, *w.end))
    assert isinstance(s.nuclide, str) and isinstance(s.axis, str)


@FUZZ
@given(st.one_of(mutated(_TRUTH, 4), json_values))
def test_fuzz_truth_json(obj):
    with tempfile.TemporaryDirectory() as d:
        file = Path(d) / "truth.json"
        file.write_text(_dump(obj))
        try:
            t = read_truth(file)
        except DatasetError as exc:
            _names_file(exc, file)
            return
    assert isinstance(t, Truth)
    for s in t.all_sources():  # second_source parameters are usable too
        assert all(math.isfinite(v) for v in (s.x, s.y, s.z, s.cps_at_1m))
    assert all(isinstance(p, dict) for p in t.effects.values())


@FUZZ
@given(st.binary(max_size=200), st.sampled_from(["scenario.json", "truth.json"]))
def test_fuzz_json_files_arbitrary_bytes(data, name):
    with tempfile.TemporaryDirectory() as d:
        file = Path(d) / name
        file.write_bytes(data)
        try:
            (read_scenario if name == "scenario.json" else read_truth)(file)
        except DatasetError as exc:
            _names_file(exc, file)


# ------------------------------------------------------------------ scene files


@FUZZ_SCENE
@given(mutated(_SCENE, 3))
def test_fuzz_scene_data(obj):
    try:
        scene = validate_scene(obj, "fuzz.toml")
    except SceneError as exc:
        assert str(exc).startswith("fuzz.toml: "), exc
        assert "field '" in str(exc) or "table/object" in str(exc) or "unknown effect" in str(exc), exc
        return
    assert isinstance(scene, Scene)
    lo, hi = np.array(scene.bounds.min), np.array(scene.bounds.max)
    assert np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi >= lo)
    for s in scene.sources:
        assert lo[0] <= s.position[0] <= hi[0] and lo[1] <= s.position[1] <= hi[1]
    assert all(w.start != w.end for w in scene.walls)
    scene.scenario(), scene.truth()  # the views the simulator writes work on every valid scene


@FUZZ_SCENE
@given(st.one_of(st.text(max_size=300).map(lambda t: ("toml", t)),
                 text_damage(DEFAULT_SCENE.read_text()).map(lambda t: ("toml", t)),
                 json_values.map(lambda v: ("json", _dump(v)))))
def test_fuzz_scene_files(case):
    kind, text = case
    with tempfile.TemporaryDirectory() as d:
        file = Path(d) / f"scene.{kind}"
        file.write_text(text, errors="surrogatepass")
        try:
            assert isinstance(load_scene(file), Scene)
        except SceneError as exc:
            _names_file(exc, file)


# ------------------------------------------------------------------ spectrum files (issue 32): the new readers

_REAL_SPECTRA = Path(__file__).resolve().parent / "data" / "real-spectra"
_SPECTRUM_SEEDS = {
    ".rcspg": b"".join((_REAL_SPECTRA / "K40.rcspg").read_bytes().splitlines(keepends=True)[:8]),
    ".ndjson": b"".join((_REAL_SPECTRA / "walk_rc103_gnss.ndjson").read_bytes().splitlines(keepends=True)[:40]),
    ".json": (_REAL_SPECTRA / "xray_rc103.ndjson").read_bytes().splitlines()[0],
    ".npes.json": (_REAL_SPECTRA.parent / "npes" / "example1_radiacode101.json").read_bytes(),
    ".csv": b"# MeasurementTime,532\nchannel,energy_keV,counts\n0,10,1\n1,12,2\n3,16,5\n2,14,3\n",
    ".xml": (_REAL_SPECTRA / "data_th232_plus_background.xml").read_bytes(),
}
FUZZ_SPECTRA = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow],
                        database=None)


@st.composite
def damaged_bytes(draw, data: bytes) -> bytes:
    """``data`` truncated, with bytes flipped, a piece deleted or junk spliced in (one to three times)."""
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["truncate", "flip", "delete", "insert"]))
        i = draw(st.integers(0, max(len(data) - 1, 0)))
        if kind == "truncate":
            data = data[:i]
        elif kind == "flip" and data:
            data = data[:i] + bytes([data[i] ^ draw(st.integers(1, 255))]) + data[i + 1:]
        elif kind == "delete":
            data = data[:i] + data[i + draw(st.integers(1, 40)):]
        else:
            data = data[:i] + draw(st.sampled_from([b"NaN", b"1e300", b"-1", b"\t", b"\n", b"}", b"\"", b"9" * 25,
                                                    b"Infinity", b"\xff\xfe", b",", b"0"])) + data[i:]
    return data


@FUZZ_SPECTRA
@given(st.sampled_from(sorted(_SPECTRUM_SEEDS)).flatmap(lambda s: st.tuples(st.just(s),
                                                                             damaged_bytes(_SPECTRUM_SEEDS[s]))))
def test_fuzz_spectrum_readers(case):
    from radseek_io.spectrum_io import SpectrumFileError, read_spectra

    suffix, data = case
    with tempfile.TemporaryDirectory() as d:
        file = Path(d) / f"fuzz{suffix}"
        file.write_bytes(data)
        try:
            spectra = read_spectra(file)
        except SpectrumFileError as exc:
            _names_file(exc, file)
            return
    for sp in spectra:
        assert np.all(np.isfinite(sp.counts)) and np.all(sp.counts >= 0) and np.all(sp.counts <= 1e12)
        assert 0 < sp.livetime <= 1e8 and all(math.isfinite(c) for c in sp.calibration)


@FUZZ_SPECTRA
@given(st.sampled_from([".ndjson", ".rcspg"]).flatmap(lambda s: st.tuples(st.just(s),
                                                                           damaged_bytes(_SPECTRUM_SEEDS[s]))))
def test_fuzz_spectrum_show_json_is_strict(case):
    """What ``radseek spectra show --json`` prints of a damaged file parses as strict JSON (no NaN)."""
    from radseek_io.spectrum_io import SpectrumFileError
    from spectra.show import describe, dumps

    suffix, data = case
    with tempfile.TemporaryDirectory() as d:
        file = Path(d) / f"fuzz{suffix}"
        file.write_bytes(data)
        try:
            text = dumps(describe(file))
        except SpectrumFileError as exc:
            _names_file(exc, file)
            return
    json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in strict JSON"))
