"""MCAP logs of a flight: every radseek zenoh topic and the vehicle's MAVLink telemetry, in one file that
the ``mcap`` Python reader, Foxglove and ``mcap`` CLI tools open.

Channels:

- ``radseek/<vehicle>/<topic>``: the zenoh payloads byte for byte. JSON topics are ``message_encoding
  json`` with a ``jsonschema`` schema generated from the dataclass in ``radseek/topics.py`` (one
  declaration: the schema cannot drift from the code); ``detector/raw`` (the board's binary frame) has
  no schema and the encoding ``radseek.board_frame`` (decode with ``radseek.board_wire.decode_frame``).
- ``mavlink/<MESSAGE>``: each MAVLink message the vehicle sent to the GCS port, as JSON
  (pymavlink's ``to_dict()``; byte arrays as lists), schema ``mavlink.<MESSAGE>``; a team's vehicles each on
  their own GCS port, ``mavlink/<vehicle>/<MESSAGE>``.

Times: ``log_time`` is the wall clock at reception (ns, so the file sorts as it was recorded);
``publish_time`` is the simulation time of the payload (its ``t`` field, or MAVLink ``time_boot_ms`` /
``time_usec``) when it has one, else the log time.

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
import os
import queue
import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import fields
from pathlib import Path
from typing import Any

from radseek import topics

log = logging.getLogger(__name__)
RAW_ENCODING = "radseek.board_frame"


def _type_schema(type_text: str) -> dict[str, Any]:
    """JSON schema of a dataclass field annotation (as text: the module uses postponed annotations)."""
    t = type_text.replace(" ", "")
    if "|None" in t:
        inner = _type_schema(t.replace("|None", ""))
        return {"anyOf": [inner, {"type": "null"}]}
    if t.startswith("list["):
        return {"type": "array", "items": _type_schema(t[5:-1])}
    if t.startswith("dict["):
        value = t[5:-1].split(",", 1)[1]
        return {"type": "object", "additionalProperties": _type_schema(value)}
    return {"float": {"type": "number"}, "int": {"type": "integer"}, "str": {"type": "string"},
            "bool": {"type": "boolean"}}.get(t, {})


def json_schema(cls: type) -> dict[str, Any]:
    """JSON schema (draft 2020-12) of a ``radseek.topics`` payload dataclass."""
    props = {f.name: _type_schema(str(f.type)) for f in fields(cls)}
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": cls.__name__, "type": "object",
            "properties": props, "description": " ".join((cls.__doc__ or "").split())}


def _jsonable(v: Any) -> Any:
    if isinstance(v, bytes | bytearray):
        return list(v)
    if isinstance(v, list | tuple):
        return [_jsonable(x) for x in v]
    if isinstance(v, float) and v != v:  # NaN is not JSON
        return None
    return v


class McapLog:
    """A thread-unsafe MCAP writer with one channel per key (created on first use)."""

    def __init__(self, path: str | Path):
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self._file = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._file, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="radseek")
        self._channels: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        self.count = 0

    def _channel(self, name: str) -> int:
        ch = self._channels.get(name)
        if ch is not None:
            return ch
        if name.startswith("mavlink/"):
            msg = name.rsplit("/", 1)[1]
            schema = {"title": f"mavlink.{msg}", "type": "object",
                      "description": f"MAVLink {msg} as pymavlink's to_dict()"}
            sid = self._writer.register_schema(f"mavlink.{msg}", "jsonschema", json.dumps(schema).encode())
            ch = self._writer.register_channel(name, "json", sid)
        else:
            topic = name.split("/", 2)[2] if name.count("/") >= 2 else name
            cls = topics.PAYLOADS.get(topic)
            if cls is None:  # binary board frames and any key we do not know: bytes, no schema
                ch = self._writer.register_channel(name, RAW_ENCODING if topic == topics.RAW_FRAME else "", 0)
            else:
                sid = self._writer.register_schema(f"radseek.{cls.__name__}", "jsonschema",
                                                   json.dumps(json_schema(cls)).encode())
                ch = self._writer.register_channel(name, "json", sid)
        self._channels[name] = ch
        return ch

    def write(self, name: str, data: bytes, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        ch = self._channel(name)
        seq = self._seq.get(name, 0)
        self._seq[name] = seq + 1
        self._writer.add_message(ch, log_time_ns, data, publish_time_ns if publish_time_ns is not None else
                                 log_time_ns, seq)
        self.count += 1

    def close(self) -> None:
        self._writer.finish()
        self._file.close()


def _sim_ns(data: bytes) -> int | None:
    try:
        t = json.loads(data).get("t")
    except (ValueError, AttributeError, UnicodeDecodeError):
        return None
    return int(t * 1e9) if isinstance(t, int | float) and t == t and t >= 0 else None


class Recorder:
    """Records zenoh topics (``session``, key expression ``key``) and MAVLink datagrams arriving on UDP
    ``mavlink_port`` (channels ``mavlink/<MESSAGE>``) and on the ``mavlink_ports`` of named vehicles (channels
    ``mavlink/<vehicle>/<MESSAGE>``) into an MCAP file, in a background writer thread. ``stop()`` finishes the
    file."""

    def __init__(self, path: str | Path, session=None, *, key: str = topics.all_keys(),
                 mavlink_port: int | None = None, mavlink_host: str = "127.0.0.1",
                 mavlink_ports: dict[str, int] | None = None):
        self.log = McapLog(path)
        self._q: queue.Queue[tuple[str, bytes, int, int | None] | None] = queue.Queue()
        self._stop = threading.Event()
        self._sub = None
        if session is not None:
            self._sub = session.declare_subscriber(key, self._on_sample)
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
        if self._socks:
            self._mav_thread = threading.Thread(target=self._mavlink_loop, name="mcap-mavlink", daemon=True)
            self._mav_thread.start()
        self._writer = threading.Thread(target=self._write_loop, name="mcap-writer", daemon=True)
        self._writer.start()

    def _on_sample(self, sample) -> None:
        data = sample.payload.to_bytes()
        self._q.put((str(sample.key_expr), data, time.time_ns(), _sim_ns(data)))

    def _mavlink_loop(self) -> None:
        import select

        os.environ.setdefault("MAVLINK20", "1")
        from pymavlink.dialects.v20 import common as M

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
        now = time.time_ns()
        for m in mav.parse_buffer(data) or []:
            kind = m.get_type()
            if kind == "BAD_DATA":
                continue
            d = {k: _jsonable(v) for k, v in m.to_dict().items()}
            sim = d.get("time_boot_ms")
            sim_ns = int(sim * 1e6) if isinstance(sim, int) else None
            if sim_ns is None and isinstance(d.get("time_usec"), int) and kind != "SYSTEM_TIME":
                sim_ns = int(d["time_usec"] * 1e3)
            self._q.put((prefix + kind, json.dumps(d).encode(), now, sim_ns))

    def _write_loop(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                return
            try:
                self.log.write(*item)
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
        self.log.close()
        return self.log.path


def read(path: str | Path) -> Iterator[tuple[str, int, int, Any]]:
    """(channel, log_time ns, publish_time ns, payload) of every message, in log-time order; JSON
    payloads decoded to dicts, binary ones as bytes."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            data = message.data
            payload = json.loads(data) if channel.message_encoding == "json" else bytes(data)
            yield channel.topic, message.log_time, message.publish_time, payload
