"""MAVLink FTP server (https://mavlink.io/en/services/ftp.html) over a small read-only virtual filesystem.

Every request inside FILE_TRANSFER_PROTOCOL gets its ACK or NAK at once, so MAVSDK's ftp plugin, MAVProxy's
``ftp`` and QGroundControl finish or fall back instead of waiting out their timeouts:

- ListDirectory: ``D<name>`` / ``F<name>\\t<size>`` entries from the requested index; NAK EOF past the last one,
  NAK FileNotFound for a path that is not a directory.
- OpenFileRO (a session, the file's size at opening), ReadFile, BurstReadFile (up to 64 kB a burst, its last
  packet marked burst_complete; NAK EOF from the file's end), TerminateSession, ResetSessions. NAK FileNotFound
  for a file that does not exist (QGC's and MAVProxy's ``@PARAM/param.pck``: PX4 has no such file either, and
  they fall back to the parameter protocol), InvalidSession, NoSessionsAvailable past ``MAX_SESSIONS`` files.
- The write commands (create, write, remove, mkdir, rmdir, open-for-write, truncate, rename): NAK FileProtected,
  the filesystem being read-only (nothing recorded can be lost); anything else (CalcFileCRC32 included): NAK
  UnknownCommand, as the spec asks of a server that does not implement an opcode.
- A request repeating the last sequence number gets the same reply again (the client's resend after a loss).

Payload (little-endian): seq u16, session u8, opcode u8, size u8, req_opcode u8, burst_complete u8, padding u8,
offset u32, data[239]; a reply's seq is the request's + 1."""

from __future__ import annotations

import logging
import posixpath
import struct
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as M

log = logging.getLogger(__name__)

HEADER = struct.Struct("<HBBBBBBI")
DATA_MAX = 251 - HEADER.size  # 239
MAX_SESSIONS = 4
BURST_MAX_BYTES = 64 * 1024  # one burst's worth; the client asks for the next one
WRITE_OPCODES = frozenset({M.MAV_FTP_OPCODE_CREATEFILE, M.MAV_FTP_OPCODE_WRITEFILE, M.MAV_FTP_OPCODE_REMOVEFILE,
                           M.MAV_FTP_OPCODE_CREATEDIRECTORY, M.MAV_FTP_OPCODE_REMOVEDIRECTORY,
                           M.MAV_FTP_OPCODE_OPENFILEWO, M.MAV_FTP_OPCODE_TRUNCATEFILE, M.MAV_FTP_OPCODE_RENAME})


@dataclass(frozen=True)
class Request:
    """One decoded FTP payload."""

    seq: int
    session: int
    opcode: int
    size: int
    req_opcode: int
    burst_complete: int
    offset: int
    data: bytes

    @classmethod
    def decode(cls, payload) -> Request:
        raw = bytes(payload)
        raw = raw + bytes(max(0, 251 - len(raw)))  # MAVLink 2 trims trailing zeros
        seq, session, opcode, size, req_opcode, burst, _pad, offset = HEADER.unpack_from(raw)
        size = min(size, DATA_MAX)
        return cls(seq, session, opcode, size, req_opcode, burst, offset, raw[HEADER.size:HEADER.size + size])

    def path(self) -> str:
        return self.data.split(b"\x00", 1)[0].decode("utf-8", "replace")


@dataclass
class VirtualFile:
    """A read-only file whose content may grow (the flight log)."""

    size: Callable[[], int]
    read: Callable[[int, int], bytes]  # (offset, count) -> bytes


class VirtualFs:
    """Files at absolute paths; directories are the paths' parents."""

    def __init__(self) -> None:
        self.files: dict[str, VirtualFile] = {}

    def add(self, path: str, file: VirtualFile) -> None:
        self.files[normalise(path)] = file

    def listdir(self, path: str) -> list[tuple[str, bool, int]] | None:
        """(name, is_dir, size) sorted by name, or None if ``path`` is no directory."""
        d = normalise(path)
        prefix = "" if d == "/" else d
        entries: dict[str, tuple[bool, int]] = {}
        for f, vf in self.files.items():
            if not f.startswith(prefix + "/"):
                continue
            head, _, rest = f[len(prefix) + 1:].partition("/")
            entries[head] = (True, 0) if rest else (False, vf.size())
        if not entries and d != "/":
            return None
        return [(n, *entries[n]) for n in sorted(entries)]


def normalise(path: str) -> str:
    return posixpath.normpath("/" + path.strip().lstrip("/")).replace("//", "/")


class FtpServer:
    """Answers FTP requests from one filesystem; ``handle`` returns the reply payloads in order."""

    def __init__(self, fs: VirtualFs):
        self.fs = fs
        self.sessions: dict[int, tuple[VirtualFile, int]] = {}  # session -> (file, size at opening)
        self._last: dict[tuple[int, int], tuple[int, list[bytes]]] = {}  # client -> (request seq, replies)

    def handle(self, payload, client: tuple[int, int] = (0, 0)) -> list[bytes]:
        req = Request.decode(payload)
        last = self._last.get(client)
        if last is not None and last[0] == req.seq and req.opcode != M.MAV_FTP_OPCODE_BURSTREADFILE:
            return last[1]  # a resend: the same answer, nothing done twice
        replies = self._answer(req)
        self._last[client] = (req.seq, replies)
        return replies

    # -- replies ---------------------------------------------------------------------------------
    @staticmethod
    def _reply(req: Request, opcode: int, data: bytes = b"", *, seq_add: int = 1, offset: int | None = None,
               session: int | None = None, burst_complete: int = 0) -> bytes:
        head = HEADER.pack((req.seq + seq_add) & 0xFFFF, req.session if session is None else session, opcode,
                           len(data), req.opcode, burst_complete, 0, req.offset if offset is None else offset)
        return head + data + bytes(DATA_MAX - len(data))

    def _ack(self, req: Request, data: bytes = b"", **kw) -> bytes:
        return self._reply(req, M.MAV_FTP_OPCODE_ACK, data, **kw)

    def _nak(self, req: Request, error: int, **kw) -> bytes:
        return self._reply(req, M.MAV_FTP_OPCODE_NAK, bytes([error]), **kw)

    def _answer(self, req: Request) -> list[bytes]:
        op = req.opcode
        if op == M.MAV_FTP_OPCODE_NONE:
            return [self._ack(req)]
        if op == M.MAV_FTP_OPCODE_LISTDIRECTORY:
            return [self._list(req)]
        if op == M.MAV_FTP_OPCODE_OPENFILERO:
            return [self._open(req)]
        if op == M.MAV_FTP_OPCODE_READFILE:
            return [self._read(req)]
        if op == M.MAV_FTP_OPCODE_BURSTREADFILE:
            return self._burst(req)
        if op == M.MAV_FTP_OPCODE_TERMINATESESSION:
            if self.sessions.pop(req.session, None) is None:
                return [self._nak(req, M.MAV_FTP_ERR_INVALIDSESSION)]
            return [self._ack(req)]
        if op == M.MAV_FTP_OPCODE_RESETSESSION:
            self.sessions.clear()
            return [self._ack(req)]
        if op in WRITE_OPCODES:
            log.info("FTP opcode %d on %r refused: read-only filesystem", op, req.path())
            return [self._nak(req, M.MAV_FTP_ERR_FILEPROTECTED)]
        log.info("FTP opcode %d not implemented: NAK UnknownCommand", op)
        return [self._nak(req, M.MAV_FTP_ERR_UNKNOWNCOMMAND)]

    def _list(self, req: Request) -> bytes:
        entries = self.fs.listdir(req.path())
        if entries is None:
            return self._nak(req, M.MAV_FTP_ERR_FILENOTFOUND)
        out = b""
        for name, is_dir, size in entries[req.offset:]:
            e = (f"D{name}" if is_dir else f"F{name}\t{size}").encode() + b"\x00"
            if len(out) + len(e) > DATA_MAX:
                break
            out += e
        if not out:
            return self._nak(req, M.MAV_FTP_ERR_EOF)
        return self._ack(req, out)

    def _open(self, req: Request) -> bytes:
        f = self.fs.files.get(normalise(req.path()))
        if f is None:
            return self._nak(req, M.MAV_FTP_ERR_FILENOTFOUND)
        free = [s for s in range(MAX_SESSIONS) if s not in self.sessions]
        if not free:
            return self._nak(req, M.MAV_FTP_ERR_NOSESSIONSAVAILABLE)
        size = f.size()
        self.sessions[free[0]] = (f, size)
        return self._ack(req, struct.pack("<I", size), session=free[0], offset=0)

    def _read(self, req: Request) -> bytes:
        s = self.sessions.get(req.session)
        if s is None:
            return self._nak(req, M.MAV_FTP_ERR_INVALIDSESSION)
        f, size = s
        if req.offset >= size:
            return self._nak(req, M.MAV_FTP_ERR_EOF)
        count = min(req.size or DATA_MAX, DATA_MAX, size - req.offset)
        return self._ack(req, f.read(req.offset, count))

    def _burst(self, req: Request) -> list[bytes]:
        s = self.sessions.get(req.session)
        if s is None:
            return [self._nak(req, M.MAV_FTP_ERR_INVALIDSESSION)]
        f, size = s
        if req.offset >= size:
            return [self._nak(req, M.MAV_FTP_ERR_EOF, burst_complete=1)]
        out, ofs, k = [], req.offset, 1
        end = min(size, req.offset + BURST_MAX_BYTES)
        while ofs < end:  # as PX4: the burst's last packet says so (burst_complete), at the file's end too
            chunk = f.read(ofs, min(DATA_MAX, end - ofs))
            last = ofs + len(chunk) >= end
            out.append(self._ack(req, chunk, seq_add=k, offset=ofs, burst_complete=int(last)))
            ofs += len(chunk)
            k += 1
        return out
