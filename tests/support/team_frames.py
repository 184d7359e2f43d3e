"""A run's recorded frames against the in-process flight of the same scene and seed (``launch.offline``,
``launch.offline_team``): the one world, flown through real processes or in one, frame for frame."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

FIELDS = ("t", "x", "y", "z", *(f"c{k:02d}" for k in range(32)))


def frames_csv_differences(path: Path, frames, label: str = "") -> tuple[list[dict[str, str]], list[str]]:
    """The rows of ``path`` (a frames.csv) and, for each row that is not ``frames``' row of the same index (time,
    position, all 32 channels), one line naming the fields that differ, the in-process value first."""
    with open(path) as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(frames) > 100, (label, len(rows), len(frames))
    diffs = []
    for i, row in enumerate(rows):
        got = (frames.t[i], frames.x[i], frames.y[i], frames.z[i], *(int(c) for c in frames.counts[i]))
        want = (float(row["t"]), float(row["x"]), float(row["y"]), float(row["z"]),
                *(int(row[f"c{k:02d}"]) for k in range(32)))
        if got != want:
            diffs.append(f"{label} frame {i} (t {want[0]:g}) differs: " + ", ".join(
                f"{name} {float(a):g} != {float(b):g}" for name, a, b in zip(FIELDS, got, want, strict=True) if a != b))
    return rows, diffs


def assert_frames_csv(path: Path, frames, label: str = "") -> list[dict[str, str]]:
    """``path`` (a frames.csv) holds exactly ``frames``: time, position and all 32 channels, row for row (a team's
    dwells are numbered across the team in the flight, per vehicle in its file: callers compare those). Returns
    the rows."""
    rows, diffs = frames_csv_differences(path, frames, label)
    assert not diffs, "; ".join(diffs[:5])
    return rows


def assert_same_team_flight(out: Path, summary: dict, scene: str, seed: int, vehicles: int = 2,
                            tmp_path_factory: pytest.TempPathFactory | None = None) -> None:
    """``out``'s per-vehicle frames.csv hold exactly the frames the in-process team flight of ``scene`` and ``seed``
    records (time, position, all 32 channels), and its error is the same. With ``tmp_path_factory`` that flight is
    flown once per test run (the tests reading one stack run compare it with the same flight)."""
    from detector_fw_sim.scene import load_scene
    from launch.offline_team import fly_team_offline

    def fly(_folder=None):
        r = fly_team_offline(load_scene(scene), vehicles, seed=seed)
        return r.error_m, r.dataset.frames

    if tmp_path_factory is None:
        error_m, f = fly()
    else:
        from tests.support.once_per_run import once_per_run

        error_m, f = once_per_run(tmp_path_factory, f"offline-team-{scene}-{vehicles}-{seed}", fly)
    assert error_m == pytest.approx(summary["error_m"], abs=1e-9)
    for v in range(vehicles):
        assert_frames_csv(out / "dataset" / f"uav{v}" / "frames.csv", f.select(f.vehicle == v), f"uav{v}")
