"""The board's binary frame: round trip, CRC rejection, stream resync, fuzzing, firmware framing."""

from __future__ import annotations

import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from detector_fw_sim.board import FRAME_PERIOD_S, Board, clamp_counts
from radseek import topics
from radseek.board_wire import (
    COUNT_MAX,
    FRAME_SIZE,
    STATUS_SATURATED,
    STATUS_STALE_POSE,
    SYNC,
    U32_MAX,
    U64_MAX,
    Frame,
    FrameConsumer,
    FrameError,
    FrameStreamDecoder,
    SequenceTracker,
    decode_frame,
    encode_frame,
    frame_to_histogram,
)

FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])

frames = st.builds(
    Frame,
    seq=st.integers(0, U32_MAX),
    board_time_us=st.integers(0, U64_MAX),
    integration_us=st.integers(0, U32_MAX),
    flags=st.integers(0, 0xFF),
    counts=st.lists(st.integers(0, COUNT_MAX), min_size=32, max_size=32).map(tuple),
)


@FUZZ
@given(frames)
def test_round_trip_is_exact(frame):
    data = encode_frame(frame)
    assert len(data) == FRAME_SIZE and data.startswith(SYNC)
    assert decode_frame(data) == frame


def test_layout_matches_the_documented_offsets():
    f = Frame(seq=0x01020304, board_time_us=0x1122334455667788, integration_us=100_000, flags=0x03,
              counts=tuple(range(1000, 1032)))
    b = encode_frame(f)
    # offsets from docs/frame-format.md
    assert b[0:2] == b"\xa5\x5a" and b[2] == 1 and b[3] == 90
    assert b[4:8] == bytes([4, 3, 2, 1])
    assert int.from_bytes(b[8:16], "little") == 0x1122334455667788
    assert int.from_bytes(b[16:20], "little") == 100_000
    assert b[20] == 0x03 and b[21] == 0
    assert [int.from_bytes(b[22 + 2 * k: 24 + 2 * k], "little") for k in range(32)] == list(range(1000, 1032))
    assert int.from_bytes(b[86:90], "little") == zlib.crc32(b[2:86])


@FUZZ
@given(frames, st.integers(0, FRAME_SIZE - 1), st.integers(1, 255))
def test_any_single_byte_corruption_is_rejected(frame, index, xor):
    # CRC-32 detects every error burst of <= 32 bits, so one corrupted byte is always caught
    # (in the sync word it is caught by the sync check instead)
    data = bytearray(encode_frame(frame))
    data[index] ^= xor
    with pytest.raises(FrameError):
        decode_frame(bytes(data))


@FUZZ
@given(frames, st.integers(0, FRAME_SIZE - 1))
def test_truncated_frame_is_rejected_with_its_length(frame, n):
    with pytest.raises(FrameError, match=f"truncated frame: {n} bytes"):
        decode_frame(encode_frame(frame)[:n])


@FUZZ
@given(st.binary(max_size=3 * FRAME_SIZE))
def test_decoder_survives_arbitrary_bytes(data):
    try:
        decode_frame(data)
    except FrameError:
        pass
    dec = FrameStreamDecoder()
    got = dec.feed(data)
    dec.close()
    s = dec.stats
    assert s.frames == len(got)
    # every input byte is accounted for: decoded, skipped, or part of a dropped candidate
    assert s.frames * FRAME_SIZE + s.bytes_skipped <= len(data)


@FUZZ
@given(
    st.lists(frames, min_size=2, max_size=5, unique_by=lambda f: f.seq),
    st.lists(st.tuples(st.sampled_from(["flip", "delete", "insert"]), st.integers(0, 10_000), st.binary(min_size=1,
                                                                                                          max_size=8)),
             max_size=6),
)
def test_mutated_stream_yields_only_original_frames(fs, mutations):
    # a real stream with bytes flipped, lost and inserted (a noisy serial line): the driver must never
    # raise and must never emit a frame that was not sent (CRC-32 false accept ~2^-32 per candidate)
    stream = bytearray(b"".join(encode_frame(f) for f in fs))
    for kind, pos, data in mutations:
        i = pos % len(stream)
        if kind == "flip":
            stream[i] ^= data[0] or 1
        elif kind == "delete":
            del stream[i: i + len(data)]
        else:
            stream[i:i] = data
        if not stream:
            break
    dec = FrameStreamDecoder()
    out = dec.feed(bytes(stream))
    dec.close()
    it = iter(fs)
    assert all(f in it for f in out)  # only sent frames, in the order sent
    # a flip or insertion spoils at most one frame, a deletion (<= 8 bytes) at most two; the decoder
    # resumes right after a rejected sync word, so every untouched frame still comes out
    assert len(out) >= len(fs) - 2 * len(mutations)


def _chunks(data: bytes, cuts: list[int]) -> list[bytes]:
    cuts = sorted({c % (len(data) + 1) for c in cuts})
    edges = [0, *cuts, len(data)]
    return [data[a:b] for a, b in zip(edges[:-1], edges[1:], strict=True)]


@FUZZ
@given(
    st.lists(frames, min_size=1, max_size=6),
    st.lists(st.binary(max_size=40), min_size=7, max_size=7),
    st.lists(st.integers(0, 10_000), max_size=12),
)
def test_stream_resyncs_through_garbage_in_any_chunking(fs, garbage, cuts):
    # garbage may contain sync words and half frames; only the real frames may come out, in order
    stream = b"".join(g + encode_frame(f) for g, f in zip(garbage, fs, strict=False)) + garbage[-1]
    dec = FrameStreamDecoder()
    out = [fr for chunk in _chunks(stream, cuts) for fr in dec.feed(chunk)]
    # garbage can, by chance, contain a valid frame only if it holds 90 bytes: it holds at most 40
    assert out == fs
    assert dec.stats.frames == len(fs)


def test_stream_counts_and_drops_corrupted_and_truncated_frames():
    b = Board()
    good = [encode_frame(b.make_frame(k, np.full(32, k))) for k in range(6)]
    corrupted = bytearray(good[1])
    corrupted[40] ^= 0xFF
    truncated = good[3][:50]
    stream = good[0] + bytes(corrupted) + good[2] + truncated + good[4] + good[5][:70]
    dec = FrameStreamDecoder()
    out = []
    for i in range(0, len(stream), 7):  # serial-port sized reads
        out += dec.feed(stream[i: i + 7])
    dec.close()
    assert [f.seq for f in out] == [0, 2, 4]
    assert dec.stats.crc_errors == 2  # the corrupted one and the truncated one (its CRC spans the next frame)
    assert dec.stats.truncated == 1  # cut off at end of stream
    assert dec.stats.dropped == 3


def test_sequence_tracker_flags_jumps_and_restarts():
    tr = SequenceTracker()
    flags = [tr.update(s) for s in (5, 6, 7, 9, 10, 3, 4)]
    assert flags == [0, 0, 0, topics.FLAG_GAP, 0, topics.FLAG_GAP, 0]
    assert tr.gaps == 2 and tr.lost == 1
    assert SequenceTracker(first_is_gap=True).update(0) == topics.FLAG_GAP


def test_board_frames_the_sim_clock_at_10_hz():
    b = Board()
    assert b.period_s == FRAME_PERIOD_S == 0.1
    assert [b.index_at(t) for t in (0.0, 0.0999, 0.1, 0.3, 2.95)] == [0, 0, 1, 3, 29]
    f = b.make_frame(29, np.zeros(32, dtype=np.int64))
    assert f.seq == 29 and f.board_time_us == 3_000_000 and f.integration_us == 100_000 and f.flags == 0
    assert b.make_frame(3, np.zeros(32), stale_pose=True).flags == STATUS_STALE_POSE


def test_counter_overflow_is_clamped_and_flagged_saturated():
    counts = np.zeros(32, dtype=np.int64)
    counts[7] = COUNT_MAX + 1
    f = Board().make_frame(0, counts)
    assert f.flags & STATUS_SATURATED and f.counts[7] == COUNT_MAX
    back = decode_frame(encode_frame(f))
    assert back.flags & STATUS_SATURATED
    counts[7] = COUNT_MAX
    assert not Board().make_frame(0, counts).flags & STATUS_SATURATED
    with pytest.raises(ValueError, match="32 channel counts"):
        clamp_counts(np.zeros(31))


def test_encode_refuses_values_that_do_not_fit():
    f = Frame(seq=U32_MAX + 1, board_time_us=0, integration_us=0, flags=0, counts=(0,) * 32)
    with pytest.raises(ValueError, match="seq"):
        encode_frame(f)
    with pytest.raises(ValueError, match="counts"):
        encode_frame(Frame(seq=0, board_time_us=0, integration_us=0, flags=0, counts=(COUNT_MAX + 1,) + (0,) * 31))



@pytest.mark.parametrize("field_name, value", [
    ("seq", 2.5), ("board_time_us", "7"), ("integration_us", None), ("flags", True),
])
def test_encode_names_a_field_that_is_not_an_integer(field_name, value):
    """A float/str/None/bool field is a ValueError naming the field, never a bare struct.error."""
    kw = dict(seq=0, board_time_us=0, integration_us=100_000, flags=0, counts=(0,) * 32)
    kw[field_name] = value
    with pytest.raises(ValueError, match=field_name):
        encode_frame(Frame(**kw))


def test_encode_names_a_count_that_is_not_an_integer_and_accepts_numpy_ints():
    with pytest.raises(ValueError, match=r"count \[3\]"):
        encode_frame(Frame(seq=0, board_time_us=0, integration_us=0, flags=0, counts=(0, 0, 0, 2.5) + (0,) * 28))
    f = Frame(seq=np.uint32(1), board_time_us=np.int64(2), integration_us=3, flags=0,
              counts=tuple(np.arange(32, dtype=np.uint16)))
    assert decode_frame(encode_frame(f)).counts == tuple(range(32))

def test_histogram_message_carries_the_frame():
    f = Board().make_frame(12, np.arange(32))
    h = frame_to_histogram(f, t=1.3, flags=topics.FLAG_GAP)
    back = topics.Histogram.from_bytes(h.to_bytes())
    assert back.seq == 12 and back.counts == list(range(32)) and back.duration == pytest.approx(0.1)
    assert back.board_time == pytest.approx(1.3) and back.flags == topics.FLAG_GAP


def test_packet_consumer_drops_bad_frames_and_flags_what_was_lost():
    b = Board()
    raw = [encode_frame(b.make_frame(k, np.full(32, k))) for k in range(3, 8)]
    corrupted = bytearray(raw[1])
    corrupted[60] ^= 0x01
    bad_version = bytearray(raw[2])
    bad_version[2] = 9
    c = FrameConsumer()
    out = [c.accept(r) for r in (raw[0], bytes(corrupted), raw[2][:89], bytes(bad_version), raw[3], raw[4])]
    assert out[1] is None and out[2] is None and out[3] is None
    assert [(f.seq, flags) for f, flags in (out[0], out[4], out[5])] == [(3, topics.FLAG_GAP), (6, topics.FLAG_GAP),
                                                                         (7, 0)]
    assert (c.stats.frames, c.stats.crc_errors, c.stats.truncated, c.stats.bad_header) == (3, 2, 1, 0)
    assert c.stats.dropped == 3 and c.tracker.lost == 2
    assert FrameConsumer().accept(encode_frame(b.make_frame(0, np.zeros(32))))[1] == 0  # frame 0: no gap
