"""Frames say which vehicle recorded each frame and which odometry walk its pose belongs to (``Frames.vehicle``,
``Frames.walk``): the team's frames set them, the fit reads them (``estimator.mle.walk_starts``), and only
frames without them fall back to telling walks apart by time running backwards."""

import numpy as np

from estimator.mle import walk_starts
from mission.team import split_walks, team_frames
from radseek.dataset import Frames


def _frames(t0: float, n: int, x0: float = 0.0) -> Frames:
    z = np.zeros(n)
    return Frames(t=t0 + 0.1 * np.arange(1, n + 1), duration=z + 0.1, x=x0 + z, y=z, z=z + 1.5, yaw=z, var_x=z,
                  var_y=z, var_z=z, dwell=np.full(n, -1), counts=np.zeros((n, 32), dtype=np.int64))


def test_team_frames_carry_vehicle_and_walk_even_when_time_never_runs_back():
    # vehicle 1 flew only after vehicle 0 had landed: time increases across the join, yet two walks
    a, b = _frames(0.0, 5), _frames(100.0, 8, x0=3.0)
    team = team_frames([a, b])
    assert sorted(np.unique(team.vehicle).tolist()) == [0, 1]
    assert walk_starts(team).sum() == 2
    walks = split_walks(team)
    assert sorted(len(w) for w in walks) == [5, 8]
    assert all(len(np.unique(w.vehicle)) == 1 for w in walks)
    # a selection keeps the columns
    sel = team.select(team.vehicle == 1)
    assert len(sel) == 8 and (sel.walk == sel.walk[0]).all()


def test_frames_without_the_columns_infer_walks_from_time_order():
    a, b = _frames(0.0, 5), _frames(0.0, 4)
    joined = Frames(**{k: np.concatenate([getattr(a, k), getattr(b, k)]) for k in Frames.__dataclass_fields__
                       if k not in ("vehicle", "walk")})
    assert joined.walk.tolist() == [0] * 5 + [1] * 4
    assert walk_starts(joined).tolist() == [True] + [False] * 4 + [True] + [False] * 3
    assert (joined.vehicle == 0).all()
    single = _frames(0.0, 6)
    assert walk_starts(single).sum() == 1


def test_frames_from_records_keep_the_boards_seq_and_flags():
    from radseek import topics
    from radseek.frame_record import FrameRecord

    pose = topics.Pose(t=0.2, x=1.0, y=2.0, z=1.5, yaw=0.0)
    recs = [FrameRecord.from_histogram(topics.Histogram(seq=k, board_time=0.1 * (k + 1), t=0.1 * (k + 1),
                                                        duration=0.1, counts=[1] * 32, flags=flag), pose, -1)
            for k, flag in ((7, 0), (9, topics.FLAG_GAP))]
    f = Frames.from_records(recs)
    assert f.seq.tolist() == [7, 9] and f.flags.tolist() == [0, topics.FLAG_GAP]
    assert f.record(1).seq == 9 and f.record(1).flags == topics.FLAG_GAP
    unknown = _frames(0.0, 3)
    assert unknown.seq.tolist() == [-1, -1, -1] and unknown.flags.tolist() == [0, 0, 0]


def test_frames_csv_board_columns_are_read_and_a_bad_one_is_named(tmp_path):
    import pytest

    from radseek.dataset import DatasetError
    from radseek_io.dataset import FrameWriter, read_frames

    f = _frames(0.0, 4)
    with FrameWriter(tmp_path, extra_columns=("seq", "flags")) as w:
        for i in range(len(f)):
            r = f.record(i)
            w.write(type(r)(**{**r.__dict__, "seq": 10 + i, "flags": i % 2}))
    read = read_frames(tmp_path / "frames.csv")
    assert read.seq.tolist() == [10, 11, 12, 13] and read.flags.tolist() == [0, 1, 0, 1]
    lines = (tmp_path / "frames.csv").read_text().splitlines()
    lines[3] = ",".join(lines[3].split(",")[:-1] + ["300"])  # flags is a u8
    (tmp_path / "frames.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=r"row 4, column 'flags': 300 is not a whole number in \[0, 255\]"):
        read_frames(tmp_path / "frames.csv")
