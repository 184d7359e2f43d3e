"""Issue 30, "Bad input": ``radseek diagnose DATASET`` (and ``radseek localize``, which reads datasets the same way,
``radseek_cli.localize_cli.read_for_cli``) refuse walls without thickness, walls that overlap and flights too short
to analyse with one line on stderr naming the file, the wall(s) or the count, exit status 2 and no traceback.

The bad datasets are lattice-clean copies with an edited scenario.json or a truncated frames.csv.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from radseek.dataset import DatasetError, Wall
from radseek_cli import diagnose_cli, localize_cli
from radseek_cli.diagnose_cli import main as diagnose
from radseek_cli.localize_cli import main as localize
from radseek_cli.localize_cli import read_for_cli
from radseek_io.dataset import read_scenario, wall_overlaps

REPO = Path(__file__).resolve().parents[1]
BASE = "lattice-clean"


def _copy(shared: Path, tmp: Path, name: str = "ds") -> Path:
    dst = tmp / name
    shutil.copytree(shared / BASE, dst)
    for p in dst.iterdir():
        p.chmod(0o644)
    return dst


def _walls(path: Path, walls: list[dict], raw: tuple[str, str] | None = None) -> Path:
    """scenario.json with ``walls``; ``raw`` replaces text in the written JSON (for a literal NaN)."""
    d = json.loads((path / "scenario.json").read_text())
    d["walls"] = walls
    text = json.dumps(d)
    if raw is not None:
        text = text.replace(*raw)
    (path / "scenario.json").write_text(text)
    return path


def _keep_frames(path: Path, n: int, extra: str = "") -> Path:
    """frames.csv cut to its header and the first ``n`` rows (plus ``extra`` text)."""
    lines = (path / "frames.csv").read_text().splitlines(keepends=True)
    (path / "frames.csv").write_text("".join(lines[: n + 1]) + extra)
    return path


def _wall(start, end, thickness=0.2, height=2.0) -> dict:
    return {"start": list(start), "end": list(end), "thickness": thickness, "height": height}


def _one_line(err: str) -> str:
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


def _refused_by_both(capsys, path: Path) -> tuple[str, str]:
    """The one stderr line of diagnose and of localize on ``path``; both exit 2 and print nothing on stdout."""
    out = []
    for prog, cli, argv in (("radseek diagnose", diagnose, ["--quiet", "--no-plots"]),
                            ("radseek localize", localize, ["--quiet"])):
        assert cli([str(path), *argv]) == 2
        captured = capsys.readouterr()
        assert captured.out == ""
        line = _one_line(captured.err)
        assert line.startswith(f"{prog}: ")
        out.append(line)
    return out[0], out[1]


# ---------------------------------------------------------------------------------------- walls without volume


@pytest.mark.parametrize(("key", "value", "raw", "shown"), [
    ("thickness", 0, None, "got 0"),
    ("thickness", 0.0, None, "got 0.0"),
    ("thickness", -0.2, None, "got -0.2"),
    ("thickness", "NAN", ('"NAN"', "NaN"), "must be finite, got nan"),  # a literal NaN (Python's json reads it)
    ("height", 0, None, "got 0"),
])
def test_walls_without_volume_are_refused_naming_wall_key_and_value(shared_datasets, tmp_path, capsys, key, value,
                                                                    raw, shown):
    bad = _wall((4, 1), (4, 3))
    bad[key] = value
    path = _walls(_copy(shared_datasets, tmp_path), [_wall((1, 1), (1, 3)), bad], raw)
    for line in _refused_by_both(capsys, path):
        assert f"{path / 'scenario.json'}: key 'walls[1].{key}' must be" in line
        assert line.endswith(shown)
    with pytest.raises(DatasetError, match=rf"scenario.json: key 'walls\[1\].{key}' must be"):
        read_scenario(path / "scenario.json")


def test_zero_thickness_message_is_exact(shared_datasets, tmp_path, capsys):
    path = _walls(_copy(shared_datasets, tmp_path), [_wall((1, 1), (1, 3)), _wall((4, 1), (4, 3), thickness=0)])
    line, _ = _refused_by_both(capsys, path)
    assert line == f"radseek diagnose: {path}/scenario.json: key 'walls[1].thickness' must be > 0 (metres), got 0"


# ---------------------------------------------------------------------------------------- overlapping walls


@pytest.mark.parametrize(("walls", "pair", "area"), [
    # the same wall listed twice: every path through it would be attenuated twice
    ([_wall((1, 1), (1, 3)), _wall((4, 1), (4, 3)), _wall((4, 1), (4, 3))], (1, 2), 0.4),
    # collinear segments overlapping by 1 m
    ([_wall((1, 1), (1, 3)), _wall((4, 1), (4, 3)), _wall((4, 2), (4, 5))], (1, 2), 0.2),
    # parallel walls 0.1 m apart, 0.2 m thick: half of each inside the other over 2 m
    ([_wall((4, 1), (4, 3)), _wall((1, 1), (1, 3)), _wall((4.1, 1), (4.1, 3))], (0, 2), 0.2),
    # a shallow (10 degree) crossing: a 1.15 m sliver
    ([_wall((2, 4), (6, 4)), _wall((2, 4 - 2 * math.tan(math.radians(10))), (6, 4 + 2 * math.tan(math.radians(10))))],
     (0, 1), 0.2 * 0.2 / math.sin(math.radians(10))),
])
def test_overlapping_walls_are_refused_naming_both(shared_datasets, tmp_path, capsys, walls, pair, area):
    path = _walls(_copy(shared_datasets, tmp_path), walls)
    found = wall_overlaps(read_scenario(path / "scenario.json").walls)
    assert [(i, j) for i, j, _, _ in found] == [pair]
    assert found[0][2] == pytest.approx(area, rel=1e-6)
    i, j = pair
    for line in _refused_by_both(capsys, path):
        assert f"{path / 'scenario.json'}: key 'walls': walls[{i}] and walls[{j}] overlap by {area:.3g} m^2" in line
        assert "trim or merge the walls" in line


def test_overlapping_walls_are_refused_before_a_long_read(shared_datasets, tmp_path, capsys):
    """The walls are checked before frames.csv is read: a broken frames.csv is not reached."""
    path = _walls(_copy(shared_datasets, tmp_path), [_wall((4, 1), (4, 3)), _wall((4, 1), (4, 3))])
    (path / "frames.csv").write_text("not a header\n")
    for line in _refused_by_both(capsys, path):
        assert "walls[0] and walls[1] overlap" in line


def test_walls_that_meet_are_accepted(shared_datasets, tmp_path, capsys):
    """Corners and T-joints whose centre lines share a point (the outdoor scene's enclosure), a right-angle
    crossing and lattice-wall's L (footprints touching along an edge) are how walls are drawn, not overlaps."""
    walls = [_wall((3, 6), (7, 6), 0.15), _wall((7, 6), (7, 7.5), 0.15), _wall((7, 7.5), (3, 7.5), 0.15),
             _wall((3, 7.5), (3, 6), 0.15), _wall((5, 6), (5, 4), 0.2),  # a T-joint below the enclosure
             _wall((8, 0.5), (8, 3.5)), _wall((6.5, 2), (9.5, 2))]  # a crossing at right angles
    path = _walls(_copy(shared_datasets, tmp_path), walls)
    ds = read_for_cli("radseek diagnose", str(path), quiet=True)
    assert ds is not None and len(ds.scenario.walls) == 7
    assert capsys.readouterr().err == ""
    assert wall_overlaps(read_scenario(shared_datasets / "lattice-wall" / "scenario.json").walls) == []


def test_shipped_scenes_and_shared_datasets_have_no_overlapping_walls(shared_datasets):
    from detector_fw_sim.scene import SCENES_DIR, load_scene

    for scene in sorted(SCENES_DIR.glob("*.toml")):
        assert wall_overlaps(load_scene(scene).scenario().walls) == [], scene.name
    for p in sorted(shared_datasets.iterdir()):
        if (p / "scenario.json").exists():
            assert wall_overlaps(read_scenario(p / "scenario.json").walls) == [], p.name


def test_overlap_area_is_exact_and_touching_walls_share_nothing():
    w = Wall((0.0, 0.0), (2.0, 0.0), 0.2, 3.0)
    assert wall_overlaps([w, Wall((2.0, 0.0), (4.0, 0.0), 0.2, 3.0)]) == []  # end to end
    assert wall_overlaps([w, Wall((0.0, 0.2), (2.0, 0.2), 0.2, 3.0)]) == []  # side by side, touching
    assert wall_overlaps([w, Wall((1.0, 0.0), (1.0, 0.0), 0.2, 3.0)]) == []  # no length, no footprint
    # rotated copies overlapping by a known area: 2 m x 0.2 m, half of it shifted out (0.1 m across)
    for deg in (0.0, 30.0, 90.0, 137.0):
        c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))

        def rot(x, y, c=c, s=s):
            return (c * x - s * y, s * x + c * y)

        a = Wall(rot(0, 0), rot(2, 0), 0.2, 3.0)
        b = Wall(rot(0.5, 0.1), rot(2.5, 0.1), 0.2, 3.0)
        (i, j, area, allowed), = wall_overlaps([a, b])
        assert (i, j) == (0, 1) and area == pytest.approx(1.5 * 0.1) and allowed == pytest.approx(0.2 * 0.2 * 2**0.5
                                                                                                  + 1e-4)


# ---------------------------------------------------------------------------------------- too few frames


def test_diagnose_refuses_fewer_than_50_usable_frames(shared_datasets, tmp_path, capsys):
    path = _keep_frames(_copy(shared_datasets, tmp_path), 49)
    assert diagnose([str(path), "--quiet", "--no-plots"]) == 2
    assert _one_line(capsys.readouterr().err) == (
        f"radseek diagnose: {path}/frames.csv: only 49 usable frames (at least 50 are needed to fit the model and "
        "test effects)")
    enough = _keep_frames(_copy(shared_datasets, tmp_path, "ds50"), 50)
    assert read_for_cli("radseek diagnose", str(enough), True, diagnose_cli.MIN_FRAMES) is not None


def test_a_skipped_truncated_row_does_not_count(shared_datasets, tmp_path, capsys):
    """50 rows of which the last is cut short (a recorder stopped mid-write): the reader's warning, then the
    refusal counting the 49 it kept."""
    path = _copy(shared_datasets, tmp_path)
    row_51 = (path / "frames.csv").read_text().splitlines()[50]
    _keep_frames(path, 49, extra=row_51[: len(row_51) // 2] + "\n")
    assert diagnose([str(path), "--quiet", "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    warning, refusal = err.strip().splitlines()
    assert warning.startswith("radseek diagnose: warning: ") and "truncated last row" in warning
    assert refusal.endswith("only 49 usable frames (at least 50 are needed to fit the model and test effects)")


@pytest.mark.parametrize("n", [1, 9])
def test_localize_refuses_fewer_frames_than_a_fit_needs(shared_datasets, tmp_path, capsys, n):
    """localize needs fewer frames than diagnose (no effects to test), as many as the in-flight estimator's first
    fit (``estimator.inflight.MIN_FRAMES``); on 1 frame it used to print an estimate with deviance/dof -0.000."""
    path = _keep_frames(_copy(shared_datasets, tmp_path), n)
    assert localize([str(path), "--quiet"]) == 2
    plural = "" if n == 1 else "s"
    assert _one_line(capsys.readouterr().err) == (
        f"radseek localize: {path}/frames.csv: only {n} usable frame{plural} (at least {localize_cli.MIN_FRAMES} "
        "are needed to fit a source's position and strength and the background)")
    enough = _keep_frames(_copy(shared_datasets, tmp_path, "ds10"), 10)
    assert read_for_cli("radseek localize", str(enough), True) is not None


# ---------------------------------------------------------------------------------------- the whole command


@pytest.mark.io
def test_radseek_diagnose_command_prints_one_line(shared_datasets, tmp_path):
    path = _walls(_copy(shared_datasets, tmp_path), [_wall((4, 1), (4, 3)), _wall((4, 2), (4, 5))])
    r = subprocess.run([sys.executable, "-m", "radseek_cli", "diagnose", str(path), "--no-plots"], cwd=REPO,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stdout == ""
    assert "walls[0] and walls[1] overlap by 0.2 m^2" in _one_line(r.stderr)


# ---------------------------------------------------------------------------------------- the effect vocabulary


def test_cli_vocabulary_is_the_backends():
    from estimator.diagnose import backend

    assert diagnose_cli.VOCABULARY is backend.VOCABULARY
    for effect in backend.VOCABULARY:
        assert diagnose_cli._parser().parse_args(["x", "--model", effect, "--add", effect]).add == [effect]


def test_unmapped_wall_is_accepted_once_the_backend_names_it(shared_datasets, tmp_path, capsys, monkeypatch):
    """``--model unmapped_wall`` / ``--add unmapped_wall`` parse (the run then stops at the short flight, before
    any fit): the CLI asks the backend, so the effect the backend adds needs no second list here."""
    from estimator.diagnose import backend

    if "unmapped_wall" not in backend.VOCABULARY:  # until the backend's open-world walls are merged
        monkeypatch.setattr(backend, "VOCABULARY", (*backend.VOCABULARY, "unmapped_wall"))
    path = _keep_frames(_copy(shared_datasets, tmp_path), 20)
    for option in ("--model", "--add"):
        assert diagnose([str(path), option, "unmapped_wall", "--quiet", "--no-plots"]) == 2
        assert "only 20 usable frames" in _one_line(capsys.readouterr().err)
    with pytest.raises(SystemExit) as exc:
        diagnose([str(path), "--add", "unmapped_walls"])
    assert exc.value.code == 2
    assert "argument --add: invalid choice: 'unmapped_walls'" in capsys.readouterr().err
