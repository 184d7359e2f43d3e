"""A team run's recorded frames against the in-process team flight of the same scene and seed
(``launch.offline_team``): the one world, flown through real processes or in one, frame for frame."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest


def assert_same_team_flight(out: Path, summary: dict, scene: str, seed: int, vehicles: int = 2) -> None:
    """``out``'s per-vehicle frames.csv hold exactly the frames the in-process team flight of ``scene`` and ``seed``
    records (time, position, all 32 channels), and its error is the same."""
    from detector_fw_sim.scene import load_scene
    from launch.offline_team import fly_team_offline

    r = fly_team_offline(load_scene(scene), vehicles, seed=seed)
    assert r.error_m == pytest.approx(summary["error_m"], abs=1e-9)
    f = r.dataset.frames
    for v in range(vehicles):
        with open(out / "dataset" / f"uav{v}" / "frames.csv") as fh:
            rows = list(csv.DictReader(fh))
        mine = f.select(f.vehicle == v)
        assert len(rows) == len(mine) > 100
        for i, row in enumerate(rows):
            got = (mine.t[i], mine.x[i], mine.y[i], mine.z[i], *(int(c) for c in mine.counts[i]))
            want = (float(row["t"]), float(row["x"]), float(row["y"]), float(row["z"]),
                    *(int(row[f"c{k:02d}"]) for k in range(32)))
            assert got == want, f"uav{v} frame {i} differs"
