"""A ULog writer (https://docs.px4.io/main/en/dev_log/ulog_file_format.html), in memory, appended as it grows.

The file PX4's logger writes and pyulog, PX4 Flight Review and PlotJuggler read: the 16-byte header (magic
``ULog\\x01\\x12\\x35``, version 1, the start timestamp in microseconds), then the definitions section (the 'B'
flag bits first, no flags set and no appended data; 'F' formats, 'I' info, 'P' initial parameters) and the data
section ('A' subscriptions, 'D' data, 'L' logged strings, 'P' parameter changes). Every message is a 3-byte
header (u16 size of the rest, u8 type) and its body, all little endian. Formats are packed, with no padding fields
(a reader sizes a record from its format), and the first field of each is ``uint64_t timestamp``.

Messages are appended whole, so any size ``size()`` reports is a file a reader parses to the end (the log is
served while it grows). Bounded like a card: past ``max_bytes`` nothing more is appended and ``full`` says so;
what is written stays."""

from __future__ import annotations

import struct
from dataclasses import dataclass

MAGIC = b"ULog\x01\x12\x35"
VERSION = 1
#: C type -> struct code (ULog's basic types)
TYPES = {"int8_t": "b", "uint8_t": "B", "int16_t": "h", "uint16_t": "H", "int32_t": "i", "uint32_t": "I",
         "int64_t": "q", "uint64_t": "Q", "float": "f", "double": "d", "bool": "?", "char": "c"}
DEFAULT_MAX_BYTES = 64 * 1024 * 1024


@dataclass(frozen=True)
class Format:
    """One message format: ``fields`` as (C type, name), arrays as ``float[4]``; ``timestamp`` first."""

    name: str
    fields: tuple[tuple[str, str], ...]

    def __post_init__(self) -> None:
        if not self.fields or self.fields[0] != ("uint64_t", "timestamp"):
            raise ValueError(f"format {self.name}: the first field must be 'uint64_t timestamp'")
        for ctype, _ in self.fields:
            _split(ctype)  # raises on an unknown type

    def text(self) -> str:
        return f"{self.name}:" + "".join(f"{t} {n};" for t, n in self.fields)

    def struct(self) -> struct.Struct:
        code = "".join(f"{n}{TYPES[t]}" if n else TYPES[t] for t, n in map(_split, (c for c, _ in self.fields)))
        return struct.Struct("<" + code)


def _split(ctype: str) -> tuple[str, int]:
    """``float[4]`` -> ("float", 4); ``double`` -> ("double", 0)."""
    base, _, rest = ctype.partition("[")
    if base not in TYPES:
        raise ValueError(f"unknown ULog type {ctype!r}")
    return base, int(rest.rstrip("]")) if rest else 0


class UlogWriter:
    """One ULog file: definitions first (``info``, ``param``, ``add_format``), then data (``subscribe``,
    ``write``, ``log``, ``param`` again for a change). Timestamps are microseconds."""

    def __init__(self, start_us: int = 0, max_bytes: int = DEFAULT_MAX_BYTES):
        self.max_bytes = max_bytes
        self.full = False
        self._data = bytearray(MAGIC + struct.pack("<BQ", VERSION, start_us))
        self._append(b"B", bytes(8) + bytes(8) + bytes(3 * 8))  # compat, incompat flags; no appended data
        self._formats: dict[str, tuple[Format, struct.Struct]] = {}
        self._ids: dict[tuple[str, int], int] = {}
        self._in_data = False

    def _append(self, kind: bytes, body: bytes) -> None:
        if self.full:
            return
        if len(body) > 0xFFFF:
            raise ValueError(f"ULog message '{kind.decode()}' of {len(body)} bytes: at most 65535")
        if len(self._data) + 3 + len(body) > self.max_bytes:
            self.full = True
            return
        self._data += struct.pack("<HB", len(body), kind[0]) + body

    def _definition(self, what: str) -> None:
        if self._in_data:
            raise RuntimeError(f"{what} after the first subscription: definitions come first")

    def add_format(self, fmt: Format) -> None:
        self._definition(f"format {fmt.name}")
        self._formats[fmt.name] = (fmt, fmt.struct())
        self._append(b"F", fmt.text().encode())

    def info(self, key: str, value: str | int) -> None:
        """An 'I' message: a string (``char[n]``) or an ``int32_t``."""
        self._definition(f"info {key}")
        if isinstance(value, str):
            raw = value.encode()
            self._append(b"I", _key(f"char[{len(raw)}] {key}") + raw)
        else:
            self._append(b"I", _key(f"int32_t {key}") + struct.pack("<i", value))

    def param(self, name: str, value: float, integer: bool) -> None:
        """A 'P' message (PX4's two parameter types): the initial value in the definitions, a change in the data
        (it takes the time of the data before it)."""
        if integer:
            self._append(b"P", _key(f"int32_t {name}") + struct.pack("<i", int(value)))
        else:
            self._append(b"P", _key(f"float {name}") + struct.pack("<f", value))

    def subscribe(self, name: str, multi_id: int = 0) -> int:
        """An 'A' message for format ``name`` (its instance ``multi_id``): the msg_id its data carries."""
        if name not in self._formats:
            raise KeyError(f"no format {name!r} defined")
        self._in_data = True
        msg_id = len(self._ids)
        self._ids[(name, multi_id)] = msg_id
        self._append(b"A", struct.pack("<BH", multi_id, msg_id) + name.encode())
        return msg_id

    def write(self, name: str, values: dict[str, object], multi_id: int = 0) -> None:
        """A 'D' message: ``values`` by field name (``timestamp`` in us), every field of the format given."""
        fmt, packer = self._formats[name]
        msg_id = self._ids[(name, multi_id)]
        flat: list = []
        for ctype, field_name in fmt.fields:
            v = values[field_name]
            if _split(ctype)[1]:
                flat.extend(v)
            else:
                flat.append(v)
        self._append(b"D", struct.pack("<H", msg_id) + packer.pack(*flat))

    def log(self, level: int, timestamp_us: int, text: str) -> None:
        """An 'L' message; ``level`` 0 (emergency) .. 7 (debug), written as PX4 does: the ASCII digit."""
        self._append(b"L", struct.pack("<BQ", ord("0") + min(max(level, 0), 7), timestamp_us) + text.encode())

    def size(self) -> int:
        return len(self._data)

    def read(self, offset: int, count: int) -> bytes:
        """Up to ``count`` bytes from ``offset`` (empty at or past the end)."""
        return bytes(self._data[offset:offset + count])


def _key(key: str) -> bytes:
    raw = key.encode()
    return struct.pack("<B", len(raw)) + raw
