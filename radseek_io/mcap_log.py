"""MCAP logs of a flight: every radseek zenoh topic, the vehicle's MAVLink telemetry and the flight in
Foxglove's well-known schemas, in one file that the ``mcap`` Python reader, Foxglove, Lichtblick and ``mcap``
CLI tools open.

Channels:

- ``radseek/<vehicle>/<topic>``: the zenoh payloads byte for byte. JSON topics are ``message_encoding
  json`` with a ``jsonschema`` schema generated from the dataclass in ``radseek/topics.py`` (one
  declaration: the schema cannot drift from the code: ``radseek.topics.json_schema``); ``detector/raw`` (the
  board's binary frame) is ``ros1`` with the ``ros1msg`` schema ``radseek.BoardFrame`` generated from the
  frame's layout (``board_frame_ros1msg``: the 90 bytes are that ROS 1 message as they are), so Foxglove shows
  its fields; ``radseek.board_wire.decode_frame`` decodes it too.
- ``radseek/<vehicle>/detector/raw/decoded``: each raw board frame decoded, as JSON (schema
  ``radseek.BoardFrameDecoded``: ``t``, ``seq``, ``board_time``, ``duration``, ``flags``, ``counts``,
  ``total``) so a generic tool can plot it; a frame that does not decode has ``error`` instead.
- ``mavlink/<MESSAGE>``: each MAVLink message the vehicle sent to the GCS port, as JSON
  (pymavlink's ``to_dict()``; byte arrays as lists, a NaN field left out, a NaN array element null), schema
  ``mavlink.<MESSAGE>`` generated from pymavlink's message definitions (:mod:`radseek_io.mavlink_json`: every
  field with its type); a team's vehicles each on their own GCS port, ``mavlink/<vehicle>/<MESSAGE>``.
- ``foxglove/...``: the flight as ``foxglove.LocationFix``, ``PoseInFrame``, ``FrameTransform`` and
  ``SceneUpdate`` (walls, plan, estimate and its ellipses) for the Map and 3D panels
  (:mod:`radseek_io.foxglove_view`, schemas :mod:`radseek_io.foxglove_schemas`).

Times are simulation time, so an 82 s simulated flight spans 82 s in the file whatever the speed-up:
``log_time`` is the message's simulation time (its ``t`` field, or MAVLink ``time_boot_ms`` / ``time_usec``)
in ns, or for a message with none (raw frames, HEARTBEAT...) the latest simulation time seen, never earlier
than the channel's previous message (monotonic per channel); ``publish_time`` is the message's own
simulation time as stamped (not clamped), else its log time. The wall-clock span of the recording is in the
file's ``radseek.recording`` metadata record.

``Recorder`` runs it in the background (zenoh subscriber + optional UDP MAVLink listener, one writer
thread); ``radseek record`` is its CLI (:mod:`radseek_cli.record_cli`); ``read`` iterates over a file's
messages decoded.
``radseek run`` runs ``radseek record`` for every flight into ``OUT/flight.mcap`` (listening on the vehicle's
``--gcs-port``), and ``radseek replay OUT/flight.mcap`` rebuilds the flight's frames from it
(``radseek_io.mcap_frames``).
"""

from __future__ import annotations

import json
import logging
import queue
import socket
import threading
import time
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from radseek import topics
from radseek.board_wire import FRAME_SIZE, WIRE_FIELDS, FrameError, decode_frame
from radseek.coordinates import Home
from radseek.dataset import Scenario
from radseek_io.foxglove_schemas import schema as foxglove_schema
from radseek_io.foxglove_view import FoxgloveView
from radseek_io.mavlink_json import dialect, mavlink_schema, message_dict

log = logging.getLogger(__name__)
#: message and schema encoding of the raw board frames (``board_frame_ros1msg``)
RAW_ENCODING, RAW_SCHEMA_ENCODING = "ros1", "ros1msg"
#: channel of the decoded raw frames, beside ``radseek/<vehicle>/detector/raw``
DECODED_SUFFIX = "/decoded"
DECODED_SCHEMA = "radseek.BoardFrameDecoded"
#: a stamp beyond this is not a simulation time (e.g. a Unix time in a MAVLink time_usec)
SIM_MAX_NS = int(topics.SIM_TIME_MAX_S * 1e9)


#: ROS 1 type of each ``struct`` format character of the board frame (``radseek.board_wire.WIRE_FIELDS``)
_ROS1_TYPES = {"s": "uint8", "B": "uint8", "H": "uint16", "I": "uint32", "Q": "uint64"}


def board_frame_ros1msg() -> str:
    """The raw board frame's layout as a ROS 1 message definition (``ros1msg``), generated from
    ``radseek.board_wire.WIRE_FIELDS``. ROS 1 serialises fixed-length arrays and integers little-endian with no
    length prefix or padding, as the board does, so the 90 bytes on ``detector/raw`` are this message byte for
    byte: the channel is ``ros1``, which Foxglove, Lichtblick and the ``mcap`` tools decode with no plug-in."""
    lines = [f"# {topics.RAW_FRAME_SCHEMA}: the spectroscopy board's frame, {FRAME_SIZE} bytes little-endian "
             "(docs/frame-format.md)"]
    for name, code in WIRE_FIELDS:
        count, kind = code[:-1], code[-1]
        lines.append(f"{_ROS1_TYPES[kind]}{f'[{count}]' if count else ''} {name}")
    return "\n".join(lines) + "\n"


def decoded_frame_schema() -> dict[str, Any]:
    """JSON schema of a decoded raw board frame (``radseek/<vehicle>/detector/raw/decoded``)."""
    num, count = {"type": "number"}, {"type": "integer", "minimum": 0}
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": DECODED_SCHEMA, "type": "object",
            "description": "One board frame of detector/raw (docs/frame-format.md) decoded by "
                           "radseek.board_wire.decode_frame; error instead of the fields when it does not decode",
            "properties": {
                "t": {**num, "description": "s, simulation time when the frame was received (the frame has none)"},
                "seq": {**count, "description": "board frame counter (u32)"},
                "board_time": {**num, "description": "s, board clock at the end of the integration"},
                "duration": {**num, "description": "s, time integrated (the board reports no dead time)"},
                "flags": {**count, "description": "status bits (radseek.topics FLAG_*)"},
                "counts": {"type": "array", "items": count, "minItems": topics.N_CHANNELS,
                           "maxItems": topics.N_CHANNELS, "description": "pulse counts, comparator channels 0..31"},
                "total": {**count, "description": "sum of counts"},
                "error": {"type": "string", "description": "why the frame did not decode"}},
            "oneOf": [{"required": ["t", "seq", "board_time", "duration", "flags", "counts", "total"]},
                      {"required": ["t", "error"]}]}


def decoded_frame(data: bytes, t: float) -> dict[str, Any]:
    """A raw board frame as the JSON of ``decoded_frame_schema`` (received at simulation time ``t``)."""
    try:
        f = decode_frame(data)
    except FrameError as exc:
        return {"t": t, "error": str(exc)}
    return {"t": t, "seq": f.seq, "board_time": f.board_time, "duration": f.duration, "flags": f.flags,
            "counts": list(f.counts), "total": f.total}


class SimTimeline:
    """Log and publish times of the messages of a flight in simulation time (see the module docstring)."""

    def __init__(self) -> None:
        self.latest_ns = 0
        self._last: dict[str, int] = {}

    def stamp(self, channel: str, sim_ns: int | None) -> tuple[int, int]:
        """(log_time, publish_time) in ns of a message on ``channel`` stamped ``sim_ns`` (None: unstamped)."""
        if sim_ns is not None and not 0 <= sim_ns <= SIM_MAX_NS:
            sim_ns = None
        if sim_ns is not None:
            self.latest_ns = max(self.latest_ns, sim_ns)
        log_ns = max(self.latest_ns if sim_ns is None else sim_ns, self._last.get(channel, 0))
        self._last[channel] = log_ns
        return log_ns, log_ns if sim_ns is None else sim_ns


class McapLog:
    """A thread-unsafe MCAP writer with one channel per key (created on first use)."""

    def __init__(self, path: str | Path):
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self._file = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._file, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="radseek")
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        self.count = 0
        self.metadata: dict[str, str] = {}  # written as the radseek.recording metadata record on close()

    def _schema(self, name: str, schema: dict[str, Any] | str, encoding: str = "jsonschema") -> int:
        sid = self._schemas.get(name)
        if sid is None:
            data = schema if isinstance(schema, str) else json.dumps(schema)
            sid = self._schemas[name] = self._writer.register_schema(name, encoding, data.encode())
        return sid

    def _channel(self, name: str, schema: tuple[str, dict[str, Any]] | None = None) -> int:
        ch = self._channels.get(name)
        if ch is not None:
            return ch
        if schema is not None:
            ch = self._writer.register_channel(name, "json", self._schema(*schema))
        elif name.startswith("mavlink/"):
            msg = name.rsplit("/", 1)[1]
            ch = self._writer.register_channel(name, "json", self._schema(f"mavlink.{msg}", mavlink_schema(msg)))
        else:
            topic = name.split("/", 2)[2] if name.count("/") >= 2 else name
            cls = topics.PAYLOADS.get(topic)
            if topic == topics.RAW_FRAME:
                ch = self._writer.register_channel(name, RAW_ENCODING, self._schema(
                    topics.RAW_FRAME_SCHEMA, board_frame_ros1msg(), RAW_SCHEMA_ENCODING))
            elif cls is None:  # any key we do not know: bytes, no schema
                ch = self._writer.register_channel(name, "", 0)
            else:
                ch = self._writer.register_channel(name, "json", self._schema(f"radseek.{cls.__name__}",
                                                                              topics.json_schema(cls)))
        self._channels[name] = ch
        return ch

    def write(self, name: str, data: bytes, log_time_ns: int, publish_time_ns: int | None = None,
              schema: tuple[str, dict[str, Any]] | None = None) -> None:
        """Write one message on channel ``name``; ``schema`` (name, JSON schema) makes a new channel JSON with
        that schema (default: the channel's by its name, as the module docstring says)."""
        ch = self._channel(name, schema)
        seq = self._seq.get(name, 0)
        self._seq[name] = seq + 1
        self._writer.add_message(ch, log_time_ns, data, publish_time_ns if publish_time_ns is not None else
                                 log_time_ns, seq)
        self.count += 1

    def close(self) -> None:
        if self.metadata:
            self._writer.add_metadata("radseek.recording", self.metadata)
        self._writer.finish()
        self._file.close()


def _sim_ns(payload: Any) -> int | None:
    """Simulation time of a decoded payload in ns: radseek's ``t``, MAVLink's ``time_boot_ms`` or
    ``time_usec``; None when it has none."""
    if not isinstance(payload, dict):
        return None
    t = payload.get("t")
    if "mavpackettype" not in payload:
        ok = isinstance(t, int | float) and not isinstance(t, bool) and 0 <= t <= topics.SIM_TIME_MAX_S
        return round(t * 1e9) if ok else None  # rounded: 39.999999999999865 s is 40 s, not 39.999999999
    if isinstance(payload.get("time_boot_ms"), int):
        return payload["time_boot_ms"] * 1_000_000
    if isinstance(payload.get("time_usec"), int) and payload["mavpackettype"] != "SYSTEM_TIME":
        return payload["time_usec"] * 1000
    return None


def _vehicles_of(mavlink_port: int | None, mavlink_ports: dict[str, int] | None) -> frozenset[str]:
    return frozenset(([topics.DEFAULT_VEHICLE] if mavlink_port is not None else []) + list(mavlink_ports or {}))


class Recorder:
    """Records zenoh topics (``session``, key expression ``key``) and MAVLink datagrams arriving on UDP
    ``mavlink_port`` (channels ``mavlink/<MESSAGE>``) and on the ``mavlink_ports`` of named vehicles (channels
    ``mavlink/<vehicle>/<MESSAGE>``) into an MCAP file, with the decoded raw frames and the Foxglove channels
    (``scenario``: the walls drawn; ``home``: the home point of vehicles whose MAVLink is not recorded), in a
    background writer thread. ``stop()`` finishes the file."""

    def __init__(self, path: str | Path, session=None, *, key: str = topics.all_keys(),
                 mavlink_port: int | None = None, mavlink_host: str = "127.0.0.1",
                 mavlink_ports: dict[str, int] | None = None, scenario: Scenario | None = None,
                 home: Home | None = None):
        self.log = McapLog(path)
        self.timeline = SimTimeline()
        self.view = FoxgloveView(scenario, home, _vehicles_of(mavlink_port, mavlink_ports))
        self._wall_start = time.time_ns()
        self._q: queue.Queue[tuple[str, bytes, Any] | None] = queue.Queue()
        self._stop = threading.Event()
        self._sub = None
        ports = ([("", mavlink_port)] if mavlink_port is not None else []) + list((mavlink_ports or {}).items())
        self._socks: dict[socket.socket, str] = {}  # socket -> channel prefix
        self._mav_thread = None
        try:
            for name, port in ports:
                sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                self._socks[sock] = f"mavlink/{name}/" if name else "mavlink/"
                sock.bind((mavlink_host, port))
        except OSError:
            for sock in self._socks:
                sock.close()
            raise
        if session is not None:
            self._sub = session.declare_subscriber(key, self._on_sample)
        if self._socks:
            self._mav_thread = threading.Thread(target=self._mavlink_loop, name="mcap-mavlink", daemon=True)
            self._mav_thread.start()
        self._writer = threading.Thread(target=self._write_loop, name="mcap-writer", daemon=True)
        self._writer.start()

    def _on_sample(self, sample) -> None:
        self._q.put((str(sample.key_expr), sample.payload.to_bytes(), None))

    def _mavlink_loop(self) -> None:
        import select

        M = dialect()
        parsers = {}
        for sock in self._socks:
            parsers[sock] = M.MAVLink(None)
            parsers[sock].robust_parsing = True
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select(list(self._socks), [], [], 0.1)
            except (OSError, ValueError):
                return
            for sock in ready:
                try:
                    data, _ = sock.recvfrom(65535)
                except OSError:
                    continue
                self._mavlink_datagram(parsers[sock], self._socks[sock], data)

    def _mavlink_datagram(self, mav, prefix: str, data: bytes) -> None:
        for m in mav.parse_buffer(data) or []:
            kind = m.get_type()
            if kind == "BAD_DATA":
                continue
            d = message_dict(m)
            self._q.put((prefix + kind, json.dumps(d).encode(), d))

    def _record(self, name: str, data: bytes, payload: Any) -> None:
        """Write one received message and what derives from it, stamped in simulation time."""
        raw = name.endswith("/" + topics.RAW_FRAME)
        if payload is None and not raw:
            try:
                payload = json.loads(data)
            except (ValueError, UnicodeDecodeError):
                payload = None
        log_ns, _ = stamps = self.timeline.stamp(name, _sim_ns(payload))
        self.log.write(name, data, *stamps)
        if raw:
            decoded = name + DECODED_SUFFIX
            self.log.write(decoded, json.dumps(decoded_frame(data, log_ns / 1e9)).encode(),
                           *self.timeline.stamp(decoded, log_ns), schema=(DECODED_SCHEMA, decoded_frame_schema()))
            return
        for channel, schema_name, msg in self.view.derive(name, payload, log_ns):
            self.log.write(channel, json.dumps(msg).encode(), *self.timeline.stamp(channel, log_ns),
                           schema=(schema_name, foxglove_schema(schema_name.split(".", 1)[1])))

    def _write_loop(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                return
            try:
                self._record(*item)
            except Exception as exc:  # noqa: BLE001 - one bad message must not end the log
                log.warning("MCAP write of %s failed: %s", item[0], exc)

    def stop(self) -> Path:
        self._stop.set()
        if self._sub is not None:
            self._sub.undeclare()
        if self._mav_thread is not None:
            self._mav_thread.join(2)
        for sock in self._socks:
            sock.close()
        self._q.put(None)
        self._writer.join(30)
        end = time.time_ns()
        self.log.metadata = {
            "time": "log_time and publish_time are simulation time (ns since the simulation started)",
            "wall_start": datetime.fromtimestamp(self._wall_start / 1e9, UTC).isoformat(),
            "wall_end": datetime.fromtimestamp(end / 1e9, UTC).isoformat(),
            "sim_end_s": f"{self.timeline.latest_ns / 1e9:.3f}"}
        self.log.close()
        return self.log.path


def read(path: str | Path) -> Iterator[tuple[str, int, int, Any]]:
    """(channel, log_time ns, publish_time ns, payload) of every message, in log-time order; JSON
    payloads decoded to dicts, binary ones (the raw board frames) as bytes."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            data = message.data
            payload = json.loads(data) if channel.message_encoding == "json" else bytes(data)
            yield channel.topic, message.log_time, message.publish_time, payload
