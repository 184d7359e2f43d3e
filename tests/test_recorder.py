"""Flight recording: pose join by time, nothing received is lost, unusable frames kept apart."""

import math

import numpy as np
import pytest

from mission.recorder import FlightRecorder, PoseHistory, flagged_rows
from radseek import topics
from radseek.dataset import Scenario
from radseek_io.dataset import read_dataset

SCEN = Scenario(channel_edges_keV=np.linspace(40, 1640, 33), background_cps=30.0, source_z=0.0,
                bounds_min=np.zeros(3), bounds_max=np.array([10.0, 10.0, 3.0]))


def pose(t, x, yaw=0.0):
    return topics.Pose(t=t, x=x, y=2 * x, z=1.5, yaw=yaw, var_x=1e-3, var_y=2e-3, var_z=1e-4)


def test_pose_interpolates_position_and_unwraps_yaw():
    h = PoseHistory()
    h.add(pose(1.0, 0.0, yaw=math.pi - 0.1))
    h.add(pose(2.0, 1.0, yaw=-math.pi + 0.1))
    mid = h.at(1.5)
    assert mid.x == pytest.approx(0.5) and mid.y == pytest.approx(1.0)
    assert abs(math.remainder(mid.yaw - math.pi, 2 * math.pi)) < 1e-9  # through +-pi, not through 0
    assert h.at(10.0) is None  # no estimate near that time
    assert h.at(2.5).x == 1.0  # within max_gap of the last estimate


def test_a_frame_from_the_past_is_kept_flagged_and_the_flight_stays_readable(tmp_path):
    """A usable frame that does not end after the last recorded one (a forged copy filling a dropped frame's
    sequence number, with t = 1.0) goes to frames_flagged.csv: frames.csv stays in time order, and nothing is lost."""
    h = PoseHistory()
    for k in range(200):
        h.add(pose(k * 0.05, k * 0.05))
    times = [0.1 * (k + 1) for k in range(40)]
    times[25] = 1.0  # the forgery, in place of 2.6
    with FlightRecorder(tmp_path / "flight", SCEN) as rec:
        for seq, t in enumerate(times):
            hist = topics.Histogram(seq=seq, board_time=t, t=t, duration=0.1, counts=[3] * 32)
            rec.record(hist, h.at(t - 0.05), dwell=0)
        rec.record(topics.Histogram(seq=99, board_time=4.0, t=4.0, duration=0.1, counts=[3] * 32), h.at(3.95), 0)
    ds = read_dataset(tmp_path / "flight")  # the reader refuses rows out of time order: this one is not
    assert list(ds.frames.t) == times[:25] + times[26:]  # and 4.0, not after the last (0.1 x 40), is flagged too
    assert rec.out_of_order == 2 and flagged_rows(tmp_path / "flight") == 2
    assert rec.received == 41 == len(ds.frames) + flagged_rows(tmp_path / "flight")


def test_every_received_frame_is_in_the_dataset(tmp_path):
    h = PoseHistory()
    for k in range(60):
        h.add(pose(k * 0.05, k * 0.05))
    rng = np.random.default_rng(0)
    flags = [0] * 20 + [topics.FLAG_STALE_POSE] * 3 + [topics.FLAG_GAP] + [topics.FLAG_CRC_ERROR] + [0] * 3
    with FlightRecorder(tmp_path / "flight", SCEN) as rec:
        for seq, fl in enumerate(flags):
            t = 0.1 * (seq + 1)
            counts = [0] * 32 if fl & topics.FLAG_STALE_POSE else rng.poisson(2, 32).tolist()
            hist = topics.Histogram(seq=seq, board_time=t, t=t, duration=0.1, counts=counts, flags=fl)
            rec.record(hist, h.at(t - 0.05), dwell=0 if seq < 10 else -1)
    ds = read_dataset(tmp_path / "flight")
    assert rec.received == len(flags) == len(ds.frames) + flagged_rows(tmp_path / "flight")
    assert flagged_rows(tmp_path / "flight") == 4  # stale x3 and CRC; a gap flag still carries good counts
    # the pose is the estimate at the frame's mid time
    assert ds.frames.x[0] == pytest.approx(0.05, abs=1e-4)
    assert ds.frames.var_y[0] == pytest.approx(2e-3)
    assert set(ds.frames.dwell) == {0, -1}
