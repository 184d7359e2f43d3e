"""The mission's lost-frame rule is decided on sim time (detector/status), not on how late a frame is:
a frame the detector says it did not send is lost at once; one it says it sent, or one it has not
reached yet, is waited for (a slow detector on a loaded host must not change the recorded flight)."""

import asyncio
import logging
from types import SimpleNamespace

from mission.key_accounts import KeyAccounts
from mission.mission_process import _Stream
from radseek import topics


def _sample(msg) -> SimpleNamespace:
    return SimpleNamespace(key_expr=topics.key(topics.DETECTOR_STATUS, "uav0"),
                           payload=SimpleNamespace(to_bytes=msg.to_bytes))


def _status(t: float, last_hist: float | None) -> SimpleNamespace:
    return _sample(topics.DetectorStatus(t=t, frames=1, stale_frames=0, crc_errors=0, last_histogram_t=last_hist))


def test_frame_fate_follows_detector_status():
    loop = asyncio.new_event_loop()
    try:
        s = _Stream(loop, recorder=None, accounts=KeyAccounts(logging.getLogger("test")))
        assert s.frame_fate(1.0)[0] == "pending"  # nothing heard: wait (only silence is judged on wall time)
        s.on_status(_status(0.9, 0.9))
        assert s.frame_fate(1.0)[0] == "pending"  # alive, behind: wait however long it takes
        s.on_status(_status(1.0, 1.0))
        assert s.frame_fate(1.0)[0] == "in_flight"  # sent, overtaken by its status: wait for it
        s.on_status(_status(1.1, 1.0))
        assert s.frame_fate(1.1)[0] == "not_sent"  # done with 1.1 and sent nothing for it: lost, at once
        assert s.frame_fate(1.0)[1] is not None
    finally:
        loop.close()
