"""A flooded run must never stall (issue 34, the CI flake of test_run_flood_summary): the mission's frame wait
(``mission.mission_process.ZenohFrames.tick``) over a real router and real sessions, with the sample a flood
makes zenoh drop on the way injected as the fault.

Under lockstep the vehicle holds at the end of the frame the mission waits for, so nothing new comes on its own:
a histogram whose end pose was dropped must still be taken (after ``POSE_WAIT_WALL_S``, recorded without it),
and a frame whose histogram and real statuses are both lost (a forger owning ``detector/status`` keeps saying
the detector is behind) must be declared lost after a bounded wall time, the flight going on; only a stack that
stays still past ``STALL_WALL_S`` stops the flight.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time

import numpy as np
import pytest

from mission import mission_process
from mission.executive import FlightStopped
from mission.key_accounts import UNKNOWN_PUBLISHER, KeyAccounts
from mission.lockstep import LockstepAck
from mission.mission_process import ZenohFrames, _Stream
from mission.recorder import FlightRecorder
from radseek import topics
from radseek.dataset import Scenario
from radseek.zenoh_session import open_session

V = "uav0"
HELD_S = 2.0  # the held-frame bound the tests give ZenohFrames (the stack's default is HELD_FRAME_WALL_S)
HIST = topics.Histogram(seq=1, board_time=0.1, t=0.1, duration=0.1, counts=[3] * 32)

pytestmark = [pytest.mark.io, pytest.mark.timeout(240)]


def _pose(t: float) -> bytes:
    return topics.Pose(t=t, x=1.0, y=2.0, z=1.5, yaw=0.0).to_bytes()


def _status(t: float, last_hist: float) -> bytes:
    return topics.DetectorStatus(t=t, frames=1, stale_frames=0, crc_errors=0, last_histogram_t=last_hist).to_bytes()


def _repeat(put, data: bytes, period_s: float, stop: threading.Event) -> threading.Thread:
    """Put ``data`` every ``period_s`` wall seconds until ``stop`` (a detector's status heartbeat)."""
    def run() -> None:
        while not stop.is_set():
            put(data)
            stop.wait(period_s)
    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th


async def _until(cond, what: str, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, what
        await asyncio.sleep(0.02)


class _Mission:
    """The mission's side as ``MissionRunner.run`` wires it: a stream on its own session, lockstep, frames."""

    def __init__(self, endpoint: str, out, **frames_kw):
        self.session = open_session(connect=endpoint)
        scenario = Scenario(channel_edges_keV=np.linspace(40, 1640, 33), background_cps=30.0, source_z=0.0,
                            bounds_min=np.zeros(3), bounds_max=np.array([10.0, 10.0, 3.0]))
        self.recorder = FlightRecorder(out, scenario)
        self.accounts = KeyAccounts(logging.getLogger("t.held"), speedup=1.0)
        self.stream = _Stream(asyncio.get_running_loop(), self.recorder, self.accounts)
        self.subs = [self.session.declare_subscriber(topics.key(topics.POSE, V), self.stream.on_pose),
                     self.session.declare_subscriber(topics.key(topics.HISTOGRAM, V), self.stream.on_histogram),
                     self.session.declare_subscriber(topics.key(topics.DETECTOR_STATUS, V), self.stream.on_status)]
        self.events: list[tuple[str, dict]] = []
        self.lockstep = LockstepAck(self.session, V)
        self.frames = ZenohFrames(self.stream, self.lockstep, V, lambda name, **kw: self.events.append((name, kw)),
                                  **frames_kw)

    def close(self) -> None:
        for s in self.subs:
            s.undeclare()
        self.lockstep.detach()
        self.stream.flush()
        self.recorder.close()
        self.session.close()


async def _held_pose_dropped(endpoint: str, out) -> tuple[_Mission, topics.Histogram | None]:
    stop = threading.Event()
    with open_session(connect=endpoint) as vs, open_session(connect=endpoint) as ds:
        m = _Mission(endpoint, out)
        try:
            pose = topics.declare_publisher(vs, topics.POSE, V)
            hist = topics.declare_publisher(ds, topics.HISTOGRAM, V)
            status = topics.declare_publisher(ds, topics.DETECTOR_STATUS, V)
            _repeat(pose.put, _pose(0.0), 0.05, stop)  # held at t = 0 until the mission's first ack
            await _until(lambda: m.stream.pose() is not None, "the mission never heard a pose")
            stop.set()
            tick = asyncio.ensure_future(m.frames.tick())
            # the vehicle steps to 0.1 and holds: its pose there is dropped on the way (the fault); the detector
            # sends the frame ending at 0.1, then says every 0.25 s that it is done with it and waits on its clock
            hist.put(HIST.to_bytes())
            stop = threading.Event()
            _repeat(status.put, _status(0.1, 0.1), 0.25, stop)
            # bounded (the old rule waited STALL_WALL_S = 120 s for a pose that never came, then stopped the flight)
            got = await asyncio.wait_for(tick, 60)
        finally:
            stop.set()
            m.close()
    return m, got


def test_a_histogram_whose_held_pose_was_dropped_is_taken_not_waited_for_for_ever(router, tmp_path):
    m, got = asyncio.run(_held_pose_dropped(router, tmp_path / "flight"))
    assert got is not None and got.t == pytest.approx(0.1) and got.counts == HIST.counts
    assert m.frames.frames_lost == 0 and not m.events, m.events
    assert m.frames.t == pytest.approx(0.1)
    # recorded once, at the pose there was (held at t = 0, nearest the frame's mid-time)
    assert m.recorder.received == 1 and len(m.stream.records) == 1
    r = m.stream.records[0]
    assert (r.t, r.x, r.y, r.z) == (pytest.approx(0.1), 1.0, 2.0, 1.5)


async def _frame_and_statuses_lost(endpoint: str, out) -> tuple[_Mission, list, BaseException | None, str]:
    stop = threading.Event()
    results: list = []
    with open_session(connect=endpoint) as vs, open_session(connect=endpoint) as ds, \
            open_session(connect=endpoint) as fs:
        m = _Mission(endpoint, out, held_frame_wall_s=HELD_S)
        stopped: BaseException | None = None
        try:
            pose = topics.declare_publisher(vs, topics.POSE, V)
            status = topics.declare_publisher(ds, topics.DETECTOR_STATUS, V)
            forger = fs.declare_publisher(topics.key(topics.DETECTOR_STATUS, V))  # bare: "unknown publisher"
            _repeat(pose.put, _pose(0.0), 0.05, stop)
            # the forger speaks first on detector/status and keeps saying the detector is behind (t = 0.05)
            _repeat(forger.put, _status(0.05, 0.0), 0.1, stop)
            await _until(lambda: m.stream.pose() is not None and m.stream.frame_fate(0.1)[1] is not None,
                         "the mission never heard the pose and the forged status")
            # the real detector's statuses (done with 0.1, sent it) are dropped as a second publisher's, and the
            # histogram of the frame ending at 0.1 is dropped on the way (the fault: it is never put)
            _repeat(status.put, _status(0.1, 0.1), 0.25, stop)
            tick = asyncio.ensure_future(m.frames.tick())
            pose.put(_pose(0.1))  # the vehicle steps to the frame's end and holds there
            results.append(await asyncio.wait_for(tick, 60))
            # the vehicle never moves again (its mission's acks unheeded, say): each frame lost in turn, then the
            # stack is taken as gone
            for _ in range(10):
                results.append(await asyncio.wait_for(m.frames.tick(), 60))
        except FlightStopped as exc:
            stopped = exc
        finally:
            stop.set()
            real = f"{status.id.zid}/{status.id.eid}"
            m.close()
    return m, results, stopped, real


def test_a_frame_lost_with_its_statuses_while_lockstep_holds_is_declared_lost_and_a_still_stack_stops(
        router, tmp_path, monkeypatch):
    monkeypatch.setattr(mission_process, "STALL_WALL_S", 3 * HELD_S + 1.0)
    m, results, stopped, real = asyncio.run(_frame_and_statuses_lost(router, tmp_path / "flight"))
    # the frame ending at 0.1 is lost (one named event for the run of losses), the next ones too, then it stops
    assert results and results[0] is None, results
    assert all(r is None for r in results)
    assert 2 <= len(results) <= 3, results  # held 2 s each: 3 x 2 s > 7 s of stall after the last pose step
    assert m.frames.frames_lost == len(results)
    assert m.frames.t == pytest.approx(0.1 * len(results))
    assert [name for name, _ in m.events] == ["frames_lost"]
    why = m.events[0][1]["why"]
    assert m.events[0][1]["after"] == pytest.approx(0.0)
    assert "lockstep holds the vehicle" in why and "pending" in why, why
    assert isinstance(stopped, FlightStopped) and "no frame and no pose" in str(stopped), stopped
    # the real statuses were heard and dropped as a second publisher's: the fault is the accounting's, named
    dropped = m.accounts.counts()[topics.key(topics.DETECTOR_STATUS, V)]["dropped_from"]
    assert dropped[real]["foreign"] > 0 and UNKNOWN_PUBLISHER not in dropped, dropped
