"""More fuzzing of the board frame codec (radseek/board_wire.py), beside tests/test_frame_codec.py.

That file fuzzes arbitrary bytes (which almost never pass the CRC), single-byte corruption, truncation and
stream resync. These add what random bytes cannot reach: frames whose CRC is *valid* but whose header
and counts are anything (a firmware bug, or a CRC collision), encoding of out-of-range fields, the
packet-mode consumer, and the histogram a decoded frame becomes. Each input gives a valid object or the
module's own error (``FrameError`` / ``ValueError`` / ``topics.PayloadError``), never another exception.
"""

from __future__ import annotations

import struct
import zlib

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from radseek import topics
from radseek.board_wire import (
    COUNT_MAX,
    FRAME_SIZE,
    SYNC,
    Frame,
    FrameConsumer,
    FrameError,
    decode_frame,
    encode_frame,
    frame_to_histogram,
)

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow], database=None)

_HEADER = struct.Struct("<2sBBIQIBB")


def _with_crc(body: bytes) -> bytes:
    """SYNC + 84 arbitrary bytes + their valid CRC-32: a frame every byte of which passed the link check."""
    frame = SYNC + body
    return frame + struct.pack("<I", zlib.crc32(frame[len(SYNC):]))


valid_crc_frames = st.one_of(
    st.binary(min_size=FRAME_SIZE - 6, max_size=FRAME_SIZE - 6).map(_with_crc),
    # mostly-right headers reach the version/length checks and the counts
    st.tuples(st.sampled_from([0, 1, 2, 255]), st.sampled_from([0, FRAME_SIZE, FRAME_SIZE + 1, 255]),
              st.binary(min_size=FRAME_SIZE - 8, max_size=FRAME_SIZE - 8))
    .map(lambda v: _with_crc(bytes([v[0], v[1]]) + v[2])),
)


@FUZZ
@given(valid_crc_frames)
def test_valid_crc_frame_decodes_or_names_the_header_field(data):
    try:
        frame = decode_frame(data)
    except FrameError as exc:
        assert "version" in str(exc) or "length field" in str(exc), exc
        return
    assert len(frame.counts) == 32 and all(0 <= c <= COUNT_MAX for c in frame.counts)
    # what decodes re-encodes to the same bytes, up to the reserved byte the decoder ignores
    again = encode_frame(frame)
    reserved = _HEADER.size - 1
    assert again[:reserved] == data[:reserved] and again[reserved + 1:-4] == data[reserved + 1:-4]
    assert decode_frame(again) == frame


@FUZZ
@given(valid_crc_frames, st.floats(allow_nan=True, allow_infinity=True), st.integers(0, 0xFF))
def test_decoded_frame_becomes_a_valid_histogram_or_a_payload_error(data, t, flags):
    try:
        frame = decode_frame(data)
    except FrameError:
        return
    try:
        hist = frame_to_histogram(frame, t, flags)
        hist.validate()
    except topics.PayloadError as exc:
        assert "field" in str(exc) or "counts" in str(exc), exc
        return
    assert topics.Histogram.from_bytes(hist.to_bytes()) == hist


wide_ints = st.one_of(st.integers(-5, 5), st.integers(-(2**70), 2**70), st.sampled_from([2**32 - 1, 2**32, 2**64 - 1,
                                                                                        2**64, COUNT_MAX + 1]))


@FUZZ
@given(seq=wide_ints, board_time_us=wide_ints, integration_us=wide_ints, flags=wide_ints,
       counts=st.lists(st.one_of(st.integers(0, COUNT_MAX), wide_ints), min_size=0, max_size=34))
def test_encode_refuses_any_unfit_frame_with_value_error(seq, board_time_us, integration_us, flags, counts):
    frame = Frame(seq=seq, board_time_us=board_time_us, integration_us=integration_us, flags=flags,
                  counts=tuple(counts))
    try:
        data = encode_frame(frame)
    except ValueError as exc:
        assert "frame" in str(exc), exc
        return
    assert len(data) == FRAME_SIZE and decode_frame(data) == frame


@FUZZ
@given(st.lists(st.one_of(valid_crc_frames, st.binary(max_size=2 * FRAME_SIZE)), max_size=8))
def test_consumer_never_raises_and_accounts_for_every_packet(packets):
    consumer = FrameConsumer()
    accepted = [consumer.accept(p) for p in packets]
    s = consumer.stats
    n_ok = sum(a is not None for a in accepted)
    assert s.frames == n_ok
    assert s.frames + s.truncated + s.crc_errors + s.bad_header == len(packets)
    for a in accepted:
        if a is not None:
            frame, fl = a
            assert isinstance(frame, Frame) and fl in (0, topics.FLAG_GAP)
