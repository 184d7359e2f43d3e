"""The mission's first lockstep ack waits for the detector (``ZenohFrames._detector_ready``), over a real router.

Acked before the detector runs, the vehicle steps to the first frame's end and a detector starting after that
begins a frame late: under load one of two same-seed runs recorded every histogram 0.1 s later than the other
(tests/test_lockstep_repro.py failed on error_m, 0.1861 against 0.1858 m). The vehicle's side is played by a
subscriber to ``mission/lockstep``; the detector by its status heartbeat and one histogram.
"""

from __future__ import annotations

import asyncio
import threading

import pytest

from radseek import topics
from radseek.zenoh_session import open_session
from tests.test_held_frame_lost import HIST, V, _Mission, _pose, _repeat, _status, _until

pytestmark = [pytest.mark.io, pytest.mark.timeout(240)]


async def _first_frame(endpoint: str, out) -> tuple[list[topics.MissionLockstep], list[topics.MissionLockstep],
                                                     topics.Histogram | None]:
    heard: list[topics.MissionLockstep] = []
    stop = threading.Event()
    with open_session(connect=endpoint) as vs, open_session(connect=endpoint) as ds:
        vs.declare_subscriber(topics.key(topics.MISSION_LOCKSTEP, V),
                              lambda s: heard.append(topics.MissionLockstep.from_bytes(s.payload.to_bytes())))
        m = _Mission(endpoint, out)
        try:
            _repeat(topics.declare_publisher(vs, topics.POSE, V).put, _pose(0.0), 0.05, stop)  # held at t = 0
            await _until(lambda: m.stream.pose() is not None, "the mission never heard a pose")
            tick = asyncio.ensure_future(m.frames.tick(first_timeout_wall_s=60.0))
            # the mission's lockstep heartbeat (every 0.5 s wall) goes on while the detector is not there yet
            await _until(lambda: len(heard) >= 3, "no mission/lockstep heartbeat reached the vehicle")
            before = list(heard)
            status = topics.declare_publisher(ds, topics.DETECTOR_STATUS, V)
            _repeat(status.put, _status(0.0, -1.0), 0.25, stop)  # the detector is up, held at frame 0
            await _until(lambda: any(h.until > 0 for h in heard), "the mission never acked once the detector spoke")
            topics.declare_publisher(ds, topics.HISTOGRAM, V).put(HIST.to_bytes())
            got = await asyncio.wait_for(tick, 60)
        finally:
            stop.set()
            m.close()
    return before, heard, got


def test_the_first_ack_waits_until_the_detector_has_spoken(router, tmp_path):
    before, heard, got = asyncio.run(_first_frame(router, tmp_path / "flight"))
    assert all(h.until == 0.0 and h.busy for h in before), before  # held at t = 0: no frame stepped
    ack = next(h for h in heard if h.until > 0)
    assert ack.until == pytest.approx(0.1) and not ack.busy
    assert got is not None and got.t == pytest.approx(0.1)
