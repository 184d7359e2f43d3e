"""The spectroscopy board's binary frame: encode, decode, and a streaming decoder (the "driver").

The board of Mascarich et al. (paper 003, sec. III-A: 32 comparators read by an ARM MCU, reported at
10 Hz) sends one fixed-size little-endian frame per 100 ms. The byte layout is documented in
``docs/frame-format.md``; in short::

    off size field
      0    2  sync word 0xA5 0x5A
      2    1  version (1)
      3    1  total frame length in bytes (90)
      4    4  seq             u32, frame counter
      8    8  board_time_us   u64, board clock at the end of the integration (µs since power-on)
     16    4  integration_us  u32, real time integrated (µs)
     20    1  status flags    u8 (STATUS_* bits, same values as radseek.topics FLAG_*)
     21    1  reserved (0)
     22   64  counts          32 x u16, comparator channel 0..31
     86    4  crc32           u32, CRC-32 (IEEE 802.3, zlib) of bytes 2..85

The same bytes could come from the real board over USB serial: ``FrameStreamDecoder`` takes an
arbitrary byte stream (any chunking, garbage, corrupted or truncated frames), resynchronises on the
sync word, counts what it drops and never raises. ``decode_frame`` decodes one complete frame (as
published on ``detector/raw``) and raises ``FrameError`` naming what is wrong. ``SequenceTracker`` is
the consumer-side check that flags lost frames (``FLAG_GAP``).
"""

from __future__ import annotations

import operator
import struct
import zlib
from dataclasses import dataclass, field

from radseek import topics
from radseek.topics import N_CHANNELS

SYNC = b"\xa5\x5a"
VERSION = 1
COUNT_MAX = 0xFFFF  # u16 channel field: a channel that counted more is clamped and flagged saturated
#: the frame's fields in wire order as (name, ``struct`` format): the one declaration of the layout, from which the
#: codec's structs are built and the MCAP log's schema of the raw frames (``radseek_io.mcap_log``)
WIRE_FIELDS = (("sync", "2s"), ("version", "B"), ("length", "B"), ("seq", "I"), ("board_time_us", "Q"),
               ("integration_us", "I"), ("status", "B"), ("reserved", "B"), ("counts", f"{N_CHANNELS}H"),
               ("crc32", "I"))
_HEADER = struct.Struct("<" + "".join(code for _, code in WIRE_FIELDS[:-2]))  # sync ... reserved
_COUNTS = struct.Struct("<" + WIRE_FIELDS[-2][1])
_CRC = struct.Struct("<" + WIRE_FIELDS[-1][1])
FRAME_SIZE = _HEADER.size + _COUNTS.size + _CRC.size  # 90 bytes
_CRC_START = len(SYNC)  # the CRC covers everything after the sync word up to the CRC itself
_CRC_END = FRAME_SIZE - _CRC.size

STATUS_SATURATED = topics.FLAG_SATURATED  # a channel counter overflowed its u16 field (clamped)
STATUS_STALE_POSE = topics.FLAG_STALE_POSE  # emulator only: no true pose, counts are not usable
KNOWN_STATUS = STATUS_SATURATED | STATUS_STALE_POSE

U32_MAX = 0xFFFFFFFF
U64_MAX = 0xFFFFFFFFFFFFFFFF


class FrameError(ValueError):
    """A frame that cannot be decoded; the message says which check failed."""


@dataclass(frozen=True)
class Frame:
    """One decoded board frame. Times in board microseconds as sent on the wire."""

    seq: int
    board_time_us: int
    integration_us: int
    flags: int
    counts: tuple[int, ...]  # 32 channel counts

    @property
    def board_time(self) -> float:
        """Board clock at the end of the integration, seconds."""
        return self.board_time_us / 1e6

    @property
    def duration(self) -> float:
        """Integrated real time, seconds."""
        return self.integration_us / 1e6

    @property
    def total(self) -> int:
        return int(sum(self.counts))


def _integer(what: str, value: object) -> int:
    """``value`` as an exact integer (Python or numpy int); a float, bool or string is a ``ValueError``."""
    if isinstance(value, bool):
        raise ValueError(f"{what}={value!r} must be an integer, not a bool")
    try:
        return operator.index(value)
    except TypeError:
        raise ValueError(f"{what}={value!r} must be an integer, not {type(value).__name__}") from None


def encode_frame(frame: Frame) -> bytes:
    """The 90-byte wire encoding of ``frame``; raises ``ValueError`` if a field does not fit."""
    if len(frame.counts) != N_CHANNELS:
        raise ValueError(f"frame needs {N_CHANNELS} counts, got {len(frame.counts)}")
    fields = {}
    for name, value, hi in (
        ("seq", frame.seq, U32_MAX),
        ("board_time_us", frame.board_time_us, U64_MAX),
        ("integration_us", frame.integration_us, U32_MAX),
        ("flags", frame.flags, 0xFF),
    ):
        fields[name] = _integer(f"frame field {name}", value)
        if not 0 <= fields[name] <= hi:
            raise ValueError(f"frame field {name}={value} does not fit its field (0..{hi})")
    counts = [_integer(f"frame count [{i}]", c) for i, c in enumerate(frame.counts)]
    if any(not 0 <= c <= COUNT_MAX for c in counts):
        raise ValueError(f"frame counts must be in 0..{COUNT_MAX} (clamp and set STATUS_SATURATED)")
    head = _HEADER.pack(SYNC, VERSION, FRAME_SIZE, fields["seq"], fields["board_time_us"],
                        fields["integration_us"], fields["flags"], 0)
    body = head + _COUNTS.pack(*counts)
    return body + _CRC.pack(zlib.crc32(body[_CRC_START:]))


def decode_frame(data: bytes | bytearray | memoryview) -> Frame:
    """Decode exactly one frame; ``FrameError`` says whether it was truncated, misframed or corrupted."""
    data = bytes(data)
    if len(data) != FRAME_SIZE:
        kind = "truncated" if len(data) < FRAME_SIZE else "oversized"
        raise FrameError(f"{kind} frame: {len(data)} bytes, expected {FRAME_SIZE}")
    sync, version, length, seq, board_us, integ_us, flags, _ = _HEADER.unpack_from(data)
    if sync != SYNC:
        raise FrameError(f"bad sync word {sync.hex()} (expected {SYNC.hex()})")
    (crc,) = _CRC.unpack_from(data, _CRC_END)
    if zlib.crc32(data[_CRC_START:_CRC_END]) != crc:
        raise FrameError(f"CRC mismatch in frame (seq field {seq})")
    if version != VERSION:
        raise FrameError(f"unsupported frame version {version} (this driver reads {VERSION})")
    if length != FRAME_SIZE:
        raise FrameError(f"frame length field {length}, expected {FRAME_SIZE}")
    counts = _COUNTS.unpack_from(data, _HEADER.size)
    return Frame(seq=seq, board_time_us=board_us, integration_us=integ_us, flags=flags, counts=counts)


@dataclass
class DecoderStats:
    """What a decoder kept and dropped (reported on ``detector/status`` and by ``radseek echo``)."""

    frames: int = 0  # good frames decoded
    crc_errors: int = 0  # a sync word and full-length frame whose CRC failed (corrupted or truncated)
    bad_header: int = 0  # sync word followed by a wrong version/length (dropped, resynchronised)
    truncated: int = 0  # frames shorter than FRAME_SIZE (packet decoding, or a stream cut off at the end)
    bytes_skipped: int = 0  # bytes discarded while hunting for the sync word

    @property
    def dropped(self) -> int:
        return self.crc_errors + self.bad_header + self.truncated


@dataclass
class FrameStreamDecoder:
    """Decode frames from a byte stream (e.g. USB serial) in any chunking; never raises on bad bytes.

    ``feed(chunk)`` returns the frames completed by this chunk. A frame whose CRC fails is dropped and
    the search restarts one byte after its sync word, so a truncated frame followed by a good one
    loses only the truncated one. ``close()`` counts a partial frame left at the end as truncated.
    """

    stats: DecoderStats = field(default_factory=DecoderStats)
    _buf: bytearray = field(default_factory=bytearray, repr=False)

    def feed(self, chunk: bytes | bytearray | memoryview) -> list[Frame]:
        self._buf += chunk
        out: list[Frame] = []
        buf = self._buf
        pos = 0
        while True:
            i = buf.find(SYNC, pos)
            if i < 0:
                # keep a trailing 0xA5 that may be the first half of the next sync word
                keep = 1 if len(buf) > pos and buf[-1] == SYNC[0] else 0
                self.stats.bytes_skipped += len(buf) - pos - keep
                pos = len(buf) - keep
                break
            self.stats.bytes_skipped += i - pos
            pos = i
            if len(buf) - pos < 4:
                break  # need version and length
            if buf[pos + 2] != VERSION or buf[pos + 3] != FRAME_SIZE:
                self.stats.bad_header += 1
                self.stats.bytes_skipped += 1
                pos += 1
                continue
            if len(buf) - pos < FRAME_SIZE:
                break  # wait for the rest
            try:
                out.append(decode_frame(memoryview(buf)[pos : pos + FRAME_SIZE]))
            except FrameError:
                self.stats.crc_errors += 1
                self.stats.bytes_skipped += 1
                pos += 1
                continue
            self.stats.frames += 1
            pos += FRAME_SIZE
        del buf[:pos]  # what is left is shorter than one frame: memory stays bounded
        return out

    def close(self) -> None:
        """End of stream: a partial frame still buffered is counted as truncated."""
        if len(self._buf) >= len(SYNC) and self._buf.startswith(SYNC):
            self.stats.truncated += 1
        else:
            self.stats.bytes_skipped += len(self._buf)
        self._buf.clear()


@dataclass
class SequenceTracker:
    """Consumer-side sequence check: ``update(seq)`` returns ``FLAG_GAP`` when frames were lost.

    A jump forward by more than one, or any step backward (a board or emulator restart), counts as a
    gap; the first frame seen is a gap only if ``first_is_gap`` (for a consumer that joins late).
    """

    first_is_gap: bool = False
    last_seq: int | None = None
    gaps: int = 0
    lost: int = 0  # frames known to be missing (forward jumps only)

    def update(self, seq: int) -> int:
        prev, self.last_seq = self.last_seq, seq
        if prev is None:
            if self.first_is_gap:
                self.gaps += 1
                return topics.FLAG_GAP
            return 0
        if seq == prev + 1:
            return 0
        self.gaps += 1
        if seq > prev + 1:
            self.lost += seq - prev - 1
        return topics.FLAG_GAP


@dataclass
class FrameConsumer:
    """Packet-mode driver for ``detector/raw`` (one frame per message): decode, count drops, flag gaps.

    ``accept(raw)`` returns ``(frame, flags)`` with ``FLAG_GAP`` in ``flags`` when frames were lost
    before this one, or ``None`` for a frame it rejected (counted in ``stats``). It never raises on bad
    bytes. ``first_is_gap`` marks the first frame as a gap unless it is frame 0 (a consumer or emulator
    that starts after the board did).
    """

    first_is_gap: bool = True
    stats: DecoderStats = field(default_factory=DecoderStats)
    tracker: SequenceTracker | None = None

    def accept(self, raw: bytes | bytearray | memoryview) -> tuple[Frame, int] | None:
        try:
            frame = decode_frame(raw)
        except FrameError as exc:
            if str(exc).startswith("truncated"):
                self.stats.truncated += 1
            elif str(exc).startswith("CRC"):
                self.stats.crc_errors += 1
            else:
                self.stats.bad_header += 1
            return None
        if self.tracker is None:
            self.tracker = SequenceTracker(first_is_gap=self.first_is_gap and frame.seq > 0)
        self.stats.frames += 1
        return frame, self.tracker.update(frame.seq)


def frame_to_histogram(frame: Frame, t: float, flags: int = 0, **extra: float | None) -> topics.Histogram:
    """The ``detector/histogram`` message for a decoded frame ending at sim time ``t``.

    ``flags`` are OR-ed with the frame's own status (e.g. ``FLAG_GAP`` from a ``SequenceTracker``).
    """
    return topics.Histogram(
        seq=frame.seq,
        board_time=frame.board_time,
        t=float(t),
        duration=frame.duration,
        counts=[int(c) for c in frame.counts],
        flags=frame.flags | flags,
        **extra,
    )
