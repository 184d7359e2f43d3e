"""Issue 12 probes on scene files: NaN, degenerate geometry and unbounded areas are SceneErrors naming the
file and field, never a scene that simulates nonsense (or runs without limit) and never a traceback."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from detector_fw_sim.scene import SceneError, bundled_scenes, load_scene, validate_scene

SOURCE = {"nuclide": "Cs-137", "position": [4.0, 3.0, 0.0], "cps_at_1m": 1000.0}


def _scene(**over) -> dict:
    d = {"sources": [dict(SOURCE)], "bounds": {"min": [0.0, 0.0, 0.0], "max": [10.0, 8.0, 0.5]}}
    d.update(over)
    return d


def _write(tmp: Path, text: str, suffix: str = ".toml") -> Path:
    p = tmp / f"scene{suffix}"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    ("toml", "field"),
    [
        ('[[sources]]\nposition = [nan, 3.7, 0.0]\ncps_at_1m = 100.0\n', r"sources\[0\]\.position\[0\]"),
        ('[[sources]]\nposition = [1.0, 2.0, 0.0]\ncps_at_1m = inf\n', r"sources\[0\]\.cps_at_1m"),
        ('[[sources]]\nposition = [1.0, 2.0, 0.0]\ncps_at_1m = 5.0\n[background]\ncps = nan\n', r"background\.cps"),
        ('[[sources]]\nposition = [1.0, 2.0, 0.0]\ncps_at_1m = 5.0\n[bounds]\nmin = [0.0, 0.0, 0.0]\n'
         'max = [10.0, nan, 0.5]\n', r"bounds\.max\[1\]"),
        ('[[sources]]\nposition = [1.0, 2.0, 0.0]\ncps_at_1m = 5.0\n[[walls]]\nstart = [nan, 0.0]\nend = [1.0, 1.0]\n'
         'thickness = 0.2\n', r"walls\[0\]\.start\[0\]"),
        ('[[sources]]\nposition = [1.0, 2.0, 0.0]\ncps_at_1m = 5.0\n[effects.pose_drift]\nenabled = true\n'
         'vx = nan\n', r"effects\.pose_drift\.vx"),
    ],
)
def test_nan_and_inf_in_a_scene_file_are_refused(tmp_path, toml, field):
    p = _write(tmp_path, toml)
    with pytest.raises(SceneError, match=rf"{p}: field '{field}': .*finite"):
        load_scene(p)


def test_zero_length_wall_is_refused():
    data = _scene(walls=[{"start": [7.0, 0.0], "end": [7.0, 0.0], "thickness": 0.2}])
    with pytest.raises(SceneError, match=r"field 'walls\[0\]': .*zero-length wall"):
        validate_scene(data, "x.toml")


@pytest.mark.parametrize("position", [[12.0, 3.0, 0.0], [4.0, -0.5, 0.0]])
def test_source_outside_the_bounds_is_refused(position):
    data = _scene(sources=[dict(SOURCE, position=position)])
    with pytest.raises(SceneError, match=r"x.toml: .*sources\[0\]\.position .* is outside bounds"):
        validate_scene(data, "x.toml")


def test_enabled_second_source_outside_the_bounds_is_refused():
    data = _scene(effects={"second_source": {"enabled": True, "x": 30.0, "y": 1.0}})
    with pytest.raises(SceneError, match=r"effects\.second_source .* is outside bounds"):
        validate_scene(data, "x.toml")
    data["effects"]["second_source"]["enabled"] = False  # a disabled effect's defaults do not matter
    validate_scene(data, "x.toml")


@pytest.mark.parametrize("lo,hi", [(-1e6, 1e6), (0.0, 5000.0)])
def test_unbounded_scene_area_is_refused(lo, hi):
    data = _scene(bounds={"min": [lo, lo, 0.0], "max": [hi, hi, 0.5]})
    with pytest.raises(SceneError, match=r"field 'bounds': .*metres expected"):
        validate_scene(data, "x.toml")


def test_far_wall_is_refused():
    data = _scene(walls=[{"start": [0.0, 0.0], "end": [1e6, 0.0], "thickness": 0.2}])
    with pytest.raises(SceneError, match=r"field 'walls\[0\]': coordinates beyond"):
        validate_scene(data, "x.toml")


@pytest.mark.parametrize(
    ("content", "suffix", "match"),
    [
        ("[1, 2]", ".json", "a scene must be a table/object, got list"),
        ('"text"', ".json", "a scene must be a table/object, got str"),
        ("[" * 100_000, ".json", "not valid JSON"),
        ("x = [" + "[" * 5000 + "]" * 5000 + "]", ".toml", "not valid TOML|field"),
    ],
)
def test_odd_scene_files_are_scene_errors(tmp_path, content, suffix, match):
    p = _write(tmp_path, content, suffix)
    with pytest.raises(SceneError, match=match):
        load_scene(p)


def test_non_utf8_scene_file_is_a_scene_error(tmp_path):
    p = tmp_path / "scene.toml"
    p.write_bytes(b'name = "\xff\xfe"\n')
    with pytest.raises(SceneError, match=rf"{p}: not UTF-8"):
        load_scene(p)


def test_bom_scene_file_is_read(tmp_path):
    p = tmp_path / "scene.json"
    p.write_text("\ufeff" + json.dumps(_scene()), encoding="utf-8")
    assert load_scene(p).sources[0].position == (4.0, 3.0, 0.0)


@pytest.mark.parametrize("name", bundled_scenes())
def test_every_bundled_scene_is_still_valid(name):
    load_scene(name)


def test_scene_size_is_capped_with_the_limit_named(tmp_path):
    """10^6 walls ran at 1.5 s of sim time per 28 s of wall: walls, sources and the file's bytes are capped, and the
    message names the limit without echoing the whole list back."""
    from radseek_io.dataset import MAX_SOURCES, MAX_WALLS

    wall = {"start": [7.0, 1.0], "end": [7.0, 3.0], "thickness": 0.2}
    with pytest.raises(SceneError, match=rf"field 'walls': List should have at most {MAX_WALLS} items") as exc:
        validate_scene(_scene(walls=[wall] * (MAX_WALLS + 1)), "x.toml")
    assert len(str(exc.value)) < 200
    with pytest.raises(SceneError, match=rf"field 'sources': List should have at most {MAX_SOURCES} items"):
        validate_scene(_scene(sources=[SOURCE] * (MAX_SOURCES + 1)), "x.toml")
    big = tmp_path / "big.json"
    big.write_text(json.dumps(_scene(description="x" * 5_000_000)))
    with pytest.raises(SceneError, match=r"big.json: \d+ bytes; a scene file is at most"):
        load_scene(big)


def test_a_scenario_with_too_many_walls_is_refused(tmp_path, shared_datasets):
    from radseek.dataset import DatasetError
    from radseek_io.dataset import MAX_WALLS, read_scenario

    d = json.loads((shared_datasets / "lattice-wall" / "scenario.json").read_text())
    d["walls"] = d["walls"] * (MAX_WALLS // len(d["walls"]) + 1)
    (tmp_path / "scenario.json").write_text(json.dumps(d))
    with pytest.raises(DatasetError, match=rf"scenario.json: key 'walls' holds \d+ walls; at most {MAX_WALLS}"):
        read_scenario(tmp_path / "scenario.json")
