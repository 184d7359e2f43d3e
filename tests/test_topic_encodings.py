"""Every sample on the stack's zenoh keys carries its encoding and schema name (radseek.topics.encoding), so a
subscriber that does not know radseek (zenoh-cli, a bridge, a ground station) can tell JSON from the binary board
frame. A real detector process publishes over a real router on loopback."""

from __future__ import annotations

import threading
import time

import pytest

from radseek import topics
from radseek.zenoh_session import open_session
from tests.test_detector_stream import Proc

pytestmark = [pytest.mark.io, pytest.mark.timeout(300)]


def test_the_contract_names_an_encoding_for_every_topic():
    for topic, cls in topics.PAYLOADS.items():
        assert topics.encoding(topic) == f"application/json;radseek.{cls.__name__}"
    assert topics.encoding(topics.RAW_FRAME) == "application/octet-stream;radseek.BoardFrame"
    with pytest.raises(KeyError):
        topics.encoding("detector/nothing")


def test_a_detectors_samples_carry_their_encodings(router):
    seen: dict[str, str] = {}
    lock = threading.Lock()

    def on_sample(sample) -> None:
        with lock:
            seen.setdefault(str(sample.key_expr), str(sample.encoding))

    want = {topics.key(t): topics.encoding(t) for t in (topics.HISTOGRAM, topics.RAW_FRAME,
                                                          topics.DETECTOR_STATUS, topics.SIM_CLOCK)}
    with open_session(connect=router) as session:
        sub = session.declare_subscriber(topics.all_keys(), on_sample)
        det = Proc("detector", "--connect", router, "--pose", "1,2,1.5,0", "--speedup", "5", "--seed", "4")
        try:
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:
                with lock:
                    if set(want) <= set(seen):
                        break
                time.sleep(0.1)
        finally:
            det.stop()
            sub.undeclare()
    with lock:
        assert {k: seen.get(k) for k in want} == want
