"""The frame record: one type from histogram + pose + dwell index to a frames.csv row and back."""

import math

import numpy as np
import pytest

from radseek import topics
from radseek.dataset import Frames
from radseek.frame_record import COLUMNS, COUNT_DTYPE, FrameRecord, usable, usable_rate
from radseek.spectrum import Spectrum
from radseek_io.dataset import FrameWriter, read_frames

EDGES = np.linspace(40, 1640, 33)


def hist(seq=3, flags=0, counts=None):
    counts = list(range(32)) if counts is None else counts
    return topics.Histogram(seq=seq, board_time=1.0, t=2.5, duration=0.1, counts=counts, flags=flags, live_time=0.09)


POSE = topics.Pose(t=2.45, x=1.25, y=-2.0, z=1.5, yaw=0.3, var_x=1e-3, var_y=2e-3, var_z=1e-4)


def test_a_record_keeps_counts_with_their_edges_and_times_in_the_declared_dtype():
    r = FrameRecord.from_histogram(hist(), POSE, dwell=4, channel_edges_keV=EDGES)
    assert r.counts.dtype == COUNT_DTYPE and r.counts.tolist() == list(range(32))
    assert r.spectrum.realtime == r.duration == 0.1 and r.spectrum.livetime == 0.09
    np.testing.assert_array_equal(r.spectrum.bin_edges_kev, EDGES)
    assert r.values() == [2.5, 0.1, 1.25, -2.0, 1.5, 0.3, 1e-3, 2e-3, 1e-4, 4, *range(32)]
    assert len(r.values()) == len(r.csv_cells()) == len(COLUMNS)
    for counts, match in ((np.zeros(31), "32 channels"), (np.full(32, 0.5), "whole numbers")):
        with pytest.raises(ValueError, match=match):  # a frame holds the board's 32 whole counts
            FrameRecord(2.5, Spectrum(counts, realtime=0.1), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1)


def test_records_write_read_and_become_frames_alike(tmp_path):
    """frames.csv holds exactly what the mission fitted: a flight replayed from it is the flight (odometry
    poses and sim times are not round numbers; 4-decimal cells moved a walled fit's basin by 0.22 m)."""
    rng = np.random.default_rng(0)
    records = []
    for k in range(3):
        x, y, z, yaw, vx = rng.uniform(-5, 5, 5)
        pose = topics.Pose(t=0.1 * k, x=x, y=y, z=z, yaw=yaw, var_x=abs(vx) * 1e-5, var_y=1 / 3, var_z=1e-300)
        h = topics.Histogram(seq=k, board_time=1.0, t=0.1 * (k + 3), duration=0.1 * 3, counts=[k] * 32, flags=0)
        records.append(FrameRecord.from_histogram(h, pose, dwell=k - 1))
    with FrameWriter(tmp_path, extra_columns=("seq", "flags")) as w:
        for r in records:
            w.write(r)
    read = read_frames(tmp_path / "frames.csv")
    direct = Frames.from_records(records)
    for name in Frames.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(read, name), getattr(direct, name), err_msg=name)
    assert direct.counts.dtype == read.counts.dtype == COUNT_DTYPE
    assert read.record(2).values() == records[2].values()
    assert len(Frames.from_records([])) == 0


def test_usable_is_one_function_of_the_flags():
    assert usable(0) and usable(topics.FLAG_GAP) and usable(topics.FLAG_SATURATED)
    assert not usable(topics.FLAG_STALE_POSE) and not usable(topics.FLAG_CRC_ERROR)
    # a saturated frame lost counts: the estimators see it, the dwell clock does not
    assert usable_rate(0) and usable_rate(topics.FLAG_GAP) and not usable_rate(topics.FLAG_SATURATED)
    assert not usable_rate(topics.FLAG_STALE_POSE | topics.FLAG_GAP)
    no_pose = FrameRecord.from_histogram(hist(), None, dwell=0)
    assert not no_pose.usable and not no_pose.has_pose and math.isnan(no_pose.x)
    assert FrameRecord.from_histogram(hist(flags=topics.FLAG_SATURATED), POSE, 0).usable
