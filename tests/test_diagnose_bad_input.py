"""Issue 30, "Bad input": ``radseek diagnose DATASET`` (and ``radseek localize``, which reads datasets the same way,
``estimator.localize_cli.read_for_cli``) refuse walls without thickness, walls that overlap and flights too short
to analyse with one line on stderr naming the file, the wall(s) or the count, exit status 2 and no traceback.

The bad datasets are lattice-clean copies with an edited scenario.json or a truncated frames.csv.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from estimator.diagnose_cli import main as diagnose
from estimator.localize_cli import main as localize
from radseek.dataset import DatasetError, read_scenario

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
