"""PoseHistory: one pose off the timeline (forged or corrupt time far ahead, stale far behind) must not
capture the history; a gap or an owner restart that a second pose confirms is followed."""

import asyncio
import logging
from types import SimpleNamespace

import pytest

from mission.key_accounts import KeyAccounts
from mission.mission_process import _Stream
from radseek import topics
from radseek.pose_history import PoseHistory


def pose(t: float, x: float = 0.0) -> topics.Pose:
    return topics.Pose(t=t, x=x, y=0.0, z=1.5, yaw=0.0, var_x=1e-3, var_y=1e-3, var_z=1e-4)


def fill(h: PoseHistory, t0: float, t1: float, dt: float = 0.1) -> None:
    for k in range(round((t1 - t0) / dt) + 1):
        t = t0 + k * dt
        assert h.add(pose(t, x=t))


def test_one_pose_far_in_the_future_is_dropped_and_the_stream_goes_on():
    h = PoseHistory(keep_s=120.0)
    fill(h, 0.0, 10.0)
    assert not h.add(pose(1e9, x=-1.0))  # held aside, not taken
    assert h.latest().t == pytest.approx(10.0)
    assert h.add(pose(10.1, x=10.1))  # the genuine stream goes on (before the fix: dropped for ever)
    fill(h, 10.2, 12.0)
    assert h.at(11.05).x == pytest.approx(11.05)
    assert h.dropped_jumps == 1 and h.restarts == 0


def test_one_stale_pose_far_behind_is_dropped():
    h = PoseHistory()
    fill(h, 100.0, 110.0)
    assert not h.add(pose(3.0))
    assert h.add(pose(110.1, x=110.1))
    assert h.at(105.0).x == pytest.approx(105.0) and h.restarts == 0


def test_an_owner_restart_confirmed_by_two_poses_starts_the_history_anew():
    h = PoseHistory()
    fill(h, 100.0, 110.0)
    assert not h.add(pose(0.0, x=0.0))
    assert h.add(pose(0.1, x=0.1))
    assert h.restarts == 1
    assert h.at(0.05).x == pytest.approx(0.05)
    assert h.at(105.0) is None  # the old timeline is gone


def test_a_real_gap_confirmed_by_two_poses_keeps_the_history():
    h = PoseHistory(keep_s=120.0)
    fill(h, 0.0, 10.0)
    assert not h.add(pose(30.0, x=30.0))
    assert h.add(pose(30.1, x=30.1))
    assert h.at(5.0).x == pytest.approx(5.0) and h.latest().t == pytest.approx(30.1)


def _sample(msg) -> SimpleNamespace:
    return SimpleNamespace(key_expr=topics.key(topics.POSE, "uav0"), payload=SimpleNamespace(to_bytes=msg.to_bytes))


def test_mission_stream_is_not_captured_by_a_far_future_pose():
    loop = asyncio.new_event_loop()
    try:
        s = _Stream(loop, recorder=None, accounts=KeyAccounts(logging.getLogger("test")))
        for k in range(50):
            s.on_pose(_sample(pose(0.1 * k, x=0.1 * k)))
        s.on_pose(_sample(pose(1e9, x=99.0)))  # schema-valid, off the timeline
        assert s.pose().t == pytest.approx(4.9)
        s.on_pose(_sample(pose(5.0, x=5.0)))
        assert s.pose().t == pytest.approx(5.0)
        assert s.pose_at(4.95).x == pytest.approx(4.95)
    finally:
        loop.close()
