"""``radseek echo KEY``: print the messages on a zenoh key readably, one line each.

``KEY`` is a topic (``detector/histogram``, resolved under ``radseek/<vehicle>/``) or a full key
expression (``radseek/uav0/detector/**``). Histograms and raw board frames print as sequence, sim
time, total rate (counts per second), a compact spectrum (unicode sparkline, one character per
channel) and flags; other radseek payloads as ``field=value`` pairs. ``--json`` prints the payload as
received (binary frames as hex). A message that does not decode prints one ``!`` line to stderr and
is counted; echo never stops on bad input. ``--stream PATH`` decodes the board's byte stream from a
serial device, file or stdin instead (the USB driver path, docs/frame-format.md).
"""

from __future__ import annotations

import argparse
import json
import math
import queue
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from radseek import topics
from radseek.zenoh_session import OPEN_ERRORS, add_arguments, session_from_args

BLOCKS = " ▁▂▃▄▅▆▇█"
FLAG_NAMES = {
    topics.FLAG_SATURATED: "SATURATED",
    topics.FLAG_STALE_POSE: "STALE_POSE",
    topics.FLAG_GAP: "GAP",
    topics.FLAG_CRC_ERROR: "CRC_ERROR",
}


def sparkline(counts: list[int] | tuple[int, ...], log: bool = False) -> str:
    """One character per channel, height relative to the largest channel (blank = zero counts)."""
    vals = [math.log1p(c) if log else float(c) for c in counts]
    top = max(vals, default=0.0)
    if top <= 0:
        return BLOCKS[0] * len(vals)
    return "".join(BLOCKS[0] if v <= 0 else BLOCKS[max(1, round(8 * v / top))] for v in vals)


def flag_text(flags: int) -> str:
    names = [name for bit, name in FLAG_NAMES.items() if flags & bit]
    unknown = flags & ~sum(FLAG_NAMES)
    if unknown:
        names.append(f"0x{unknown:02x}")
    return ",".join(names) if names else "-"


def resolve_key(key: str, vehicle: str) -> str:
    """A full key expression: ``key`` itself if it starts with ``radseek/``, else the vehicle's topic."""
    key = key.strip("/")
    if not key:
        raise ValueError("empty key")
    if key.startswith(topics.PREFIX + "/") or key == "**":
        return key
    return topics.key(key, vehicle)


def _topic(full_key: str) -> str | None:
    try:
        return topics.topic_of(full_key)
    except ValueError:
        return None


def _fmt_value(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.3f}"
    if isinstance(v, list) and len(v) > 4:
        return f"[{len(v)} items]"
    if isinstance(v, list | dict):
        return json.dumps(v, separators=(",", ":"))
    return str(v)


@dataclass
class Formatter:
    """Turns (key, payload) into one line; keeps per-key message rate and counts bad messages."""

    log: bool = False
    bad: int = 0
    _arrivals: dict[str, deque[float]] = field(default_factory=dict)

    def rate(self, key: str, wall: float) -> float:
        """Messages per wall second on ``key`` over its last 20 arrivals."""
        q = self._arrivals.setdefault(key, deque(maxlen=20))
        q.append(wall)
        return (len(q) - 1) / (q[-1] - q[0]) if len(q) > 1 and q[-1] > q[0] else 0.0

    def spectrum_line(self, seq: int, t: float | None, duration: float, counts: list[int] | tuple[int, ...],
                      flags: int) -> str:
        total = sum(counts)
        cps = total / duration if duration > 0 else 0.0
        when = f"t={t:9.3f}s" if t is not None else " " * 12
        return (f"seq={seq:<7d} {when} {total:6d} cts {cps:9.1f} cps |{sparkline(counts, self.log)}| "
                f"flags={flag_text(flags)}")

    def format(self, key: str, payload: bytes, wall: float | None = None) -> str:
        """The readable line for one message; raises ``ValueError`` (incl. PayloadError, FrameError)."""
        wall = time.monotonic() if wall is None else wall
        hz = self.rate(key, wall)
        topic = _topic(key)
        body = self._body(topic, payload)
        return f"{key} [{hz:5.1f} Hz] {body}"

    def _body(self, topic: str | None, payload: bytes) -> str:
        if topic == topics.RAW_FRAME:
            from radseek.board_wire import decode_frame  # the driver; imported only when needed

            f = decode_frame(payload)
            return self.spectrum_line(f.seq, None, f.duration, f.counts, f.flags) + f" board={f.board_time:.3f}s"
        if topic == topics.HISTOGRAM:
            h = topics.Histogram.from_bytes(payload)
            return self.spectrum_line(h.seq, h.t, h.duration, h.counts, h.flags)
        if topic in topics.PAYLOADS:
            msg = topics.PAYLOADS[topic].from_bytes(payload).to_dict()
        else:
            try:
                msg = json.loads(payload)
            except (UnicodeDecodeError, json.JSONDecodeError):
                return f"<{len(payload)} bytes> {payload[:32].hex()}"
            if not isinstance(msg, dict):
                return json.dumps(msg)
        return " ".join(f"{k}={_fmt_value(v)}" for k, v in msg.items() if v is not None)

    def safe_format(self, key: str, payload: bytes, wall: float | None = None) -> tuple[str, bool]:
        """(line, ok): a bad message becomes a ``!`` line naming the key and the error."""
        try:
            return self.format(key, payload, wall), True
        except (ValueError, TypeError) as exc:
            self.bad += 1
            return f"! {key}: dropped ({exc}) [{self.bad} bad so far]", False


def raw_line(key: str, payload: bytes) -> str:
    """``--json``: the payload as received (JSON text, or hex for binary)."""
    try:
        return f"{key} {payload.decode()}"
    except UnicodeDecodeError:
        return f"{key} {payload.hex()}"


def echo_stream(path: str, fmt: Formatter, count: int = 0, chunk: int = 64) -> int:
    """``--stream``: decode a board byte stream (USB serial device, FIFO, file, ``-`` = stdin) and print it.

    Returns the number of frames printed; corrupted and truncated frames are counted and reported at
    the end (and as they are found), never fatal.
    """
    from radseek.board_wire import FrameStreamDecoder

    dec = FrameStreamDecoder()
    shown, dropped = 0, 0
    src = sys.stdin.buffer if path == "-" else open(path, "rb", buffering=0)
    try:
        while count <= 0 or shown < count:
            data = src.read(chunk)
            if not data:
                break
            for f in dec.feed(data):
                print(f"{path} {fmt.spectrum_line(f.seq, None, f.duration, f.counts, f.flags)} "
                      f"board={f.board_time:.3f}s", flush=True)
                shown += 1
            if dec.stats.dropped > dropped:
                dropped = dec.stats.dropped
                print(f"! {path}: dropped a bad frame ({dropped} so far)", file=sys.stderr, flush=True)
    finally:
        if src is not sys.stdin.buffer:
            src.close()
    dec.close()
    s = dec.stats
    print(f"{path}: {s.frames} frames, {s.crc_errors} CRC errors, {s.bad_header} bad headers, "
          f"{s.truncated} truncated, {s.bytes_skipped} bytes skipped", file=sys.stderr, flush=True)
    return shown


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="radseek echo", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("key", nargs="?", help="topic (detector/histogram) or key expression (radseek/uav0/**)")
    p.add_argument("--stream", metavar="PATH",
                   help="instead of zenoh, decode board frames from a byte stream (serial device, file, - = stdin)")
    p.add_argument("--json", action="store_true", help="print payloads as received (binary as hex)")
    p.add_argument("--log", action="store_true", help="log-scaled spectrum sparkline")
    p.add_argument("-n", "--count", type=int, default=0, help="exit after N messages (default: run until Ctrl-C)")
    p.add_argument("--duration", type=float, default=0.0, help="exit after S wall seconds (default: never)")
    add_arguments(p)
    args = p.parse_args(argv)
    if args.stream:
        try:
            echo_stream(args.stream, Formatter(log=args.log), args.count)
        except OSError as exc:
            print(f"radseek echo: {exc}", file=sys.stderr)
            return 1
        return 0
    if args.key is None:
        p.error("give a KEY (or --stream PATH)")
    try:
        key = resolve_key(args.key, args.vehicle_name)
    except ValueError as exc:
        p.error(str(exc))
    try:
        session = session_from_args(args, wait_for_router_s=3.0)  # say so at once when no router answers
    except OPEN_ERRORS as exc:
        print(f"radseek echo: {exc}", file=sys.stderr)
        return 1
    inbox: queue.Queue[tuple[str, bytes, float]] = queue.Queue()
    sub = session.declare_subscriber(
        key, lambda s: inbox.put((str(s.key_expr), s.payload.to_bytes(), time.monotonic()))
    )
    fmt = Formatter(log=args.log)
    shown = 0
    deadline = time.monotonic() + args.duration if args.duration > 0 else math.inf
    try:
        while shown < args.count or args.count <= 0:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            try:
                k, payload, wall = inbox.get(timeout=min(remaining, 0.5))
            except queue.Empty:
                continue
            if args.json:
                print(raw_line(k, payload), flush=True)
            else:
                line, ok = fmt.safe_format(k, payload, wall)
                print(line, file=sys.stdout if ok else sys.stderr, flush=True)
            shown += 1
    except KeyboardInterrupt:
        pass
    finally:
        sub.undeclare()
        session.close()
    return 0
