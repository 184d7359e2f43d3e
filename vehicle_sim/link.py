"""MAVLink 2 over UDP, the way PX4 SITL does it: one socket per endpoint, bound on loopback, sending to
the well-known port (14540 API/offboard, 14550 GCS) and answering whoever last wrote to it.

Also here: MAVLink 2 signing (outgoing: pymavlink; incoming: verified here, see ``SignatureCheck``; key
from a file) and fault injection (``drop_rate``: each datagram in either direction is lost with that
probability, seeded).

Every datagram is parsed on its own (``decode_datagram``): nothing of one datagram carries over to the
next, so a truncated or garbage datagram cannot swallow the commands that follow it.
"""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
import logging
import os
import select
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")

import numpy as np  # noqa: E402
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

from radseek.payload_drops import worth_reporting  # noqa: E402

log = logging.getLogger(__name__)

SIGNING_EPOCH_S = 1420070400  # MAVLink signing timestamps count 10 us units since 2015-01-01
TICKS_PER_S = 100_000
STALE_NEW_STREAM_S = 60.0  # a new stream may start at most this far behind our clock (the spec's minute)
MAX_AHEAD_S = 60.0  # a timestamp further ahead of our clock is refused, even correctly signed
MAX_DECODE_FAILURES = 32  # per datagram: bounds the work a hostile datagram can cause
RESOLVE_EVERY_S = 2.0  # a remote given by name is looked up again this often (a restarted container moves)
_STX_V1, _STX_V2, _IFLAG_SIGNED, _SIG_LEN = 0xFE, 0xFD, 0x01, 13


def load_signing_key(path: str | Path) -> bytes:
    """A 32-byte secret: a file of 64 hex digits, or any other text hashed with SHA-256 (MAVProxy's
    ``signing setup PASSPHRASE`` convention)."""
    text = Path(path).read_text().strip()
    try:
        key = bytes.fromhex(text)
        if len(key) == 32:
            return key
    except ValueError:
        pass
    if not text:
        raise ValueError(f"signing key file {path} is empty")
    return hashlib.sha256(text.encode()).digest()


def signing_timestamp(wall_time_s: float) -> int:
    """MAVLink signing timestamp (10 us units since 2015-01-01) for a Unix time."""
    return int((max(wall_time_s, SIGNING_EPOCH_S) - SIGNING_EPOCH_S) * TICKS_PER_S)


@dataclass
class LinkStats:
    rx_packets: int = 0
    tx_packets: int = 0
    dropped_rx: int = 0
    dropped_tx: int = 0
    bad_data: int = 0  # datagrams holding bytes that are no valid frame (garbage, truncated, bad CRC)
    rejected_signature: int = 0  # frames refused by signing: unsigned, wrong signature, stale/replayed/future
    unknown: int = 0  # well-framed messages of an id this dialect does not know
    unresolved_tx: int = 0  # messages not sent: the remote is a name not (yet) resolved, and no peer has spoken


def decode_datagram(decoder: mavlink.MAVLink, data: bytes) -> tuple[list[tuple[bytes, object]], int]:
    """The (frame bytes, message) pairs of one datagram, and how many unusable stretches it held.

    Stateless per datagram. Garbage, a frame that does not fit the datagram, a bad header or a bad CRC
    is skipped by resynchronising on the next start byte, so a frame behind garbage is still found;
    after ``MAX_DECODE_FAILURES`` failed decodes the rest of the datagram is dropped. Unknown message
    ids (no CRC to check them by) are returned as pymavlink's MAVLink_unknown and consume their frame.
    """
    out: list[tuple[bytes, object]] = []
    bad = failures = 0
    i, n = 0, len(data)
    while i < n:
        stx = data[i]
        if stx not in (_STX_V1, _STX_V2):
            nxt = [k for k in (data.find(b"\xfd", i), data.find(b"\xfe", i)) if k >= 0]
            i = min(nxt) if nxt else n
            bad += 1
            continue
        flen = None
        if stx == _STX_V2 and n - i >= 3 and not data[i + 2] & ~_IFLAG_SIGNED & 0xFF:
            flen = 12 + data[i + 1] + (_SIG_LEN if data[i + 2] & _IFLAG_SIGNED else 0)
        elif stx == _STX_V1 and n - i >= 2:
            flen = 8 + data[i + 1]
        if flen is None or i + flen > n:  # bad header, or truncated: look for a frame further on
            bad += 1
            i += 1
            continue
        frame = bytes(data[i:i + flen])
        try:
            msg = decoder.decode(bytearray(frame))
        except Exception:  # noqa: BLE001 - MAVError, struct.error, ...: not a frame after all
            bad += 1
            failures += 1
            if failures >= MAX_DECODE_FAILURES:
                break
            i += 1
            continue
        out.append((frame, msg))
        i += flen
    return out, bad


class SignatureCheck:
    """Incoming MAVLink 2 signature verification for one endpoint, in the order that keeps forgeries
    harmless: the signature (SHA-256 over key + frame) first, then the timestamp, and only then is any
    state changed. pymavlink's ``check_signature`` stores the stream timestamp *before* it checks the
    signature, so one forged frame with a far-future timestamp would lock the real sender out.

    Streams are keyed (link_id, sysid, compid), one table per endpoint. A timestamp must exceed the
    stream's last one; a new stream may not start more than ``STALE_NEW_STREAM_S`` behind our clock;
    no timestamp may be more than ``MAX_AHEAD_S`` ahead of it (our clock would otherwise be dragged
    towards 2^48, where it wraps and every peer would refuse what we send).
    """

    def __init__(self, key: bytes, now: Callable[[], int]):
        self.key = key
        self.now = now  # our clock, in signing ticks
        self.streams: dict[tuple[int, int, int], int] = {}

    def verify(self, frame: bytes) -> str | None:
        """None if ``frame`` is authentic and fresh (its timestamp is then recorded), else the reason."""
        if frame[0] != _STX_V2 or not frame[2] & _IFLAG_SIGNED or len(frame) < 12 + _SIG_LEN:
            return "unsigned"
        expected = hashlib.sha256(self.key + frame[:-6]).digest()[:6]
        if not hmac.compare_digest(expected, frame[-6:]):
            return "wrong signature"
        link_id, timestamp = frame[-13], int.from_bytes(frame[-12:-6], "little")
        stream = (link_id, frame[5], frame[6])
        now = self.now()
        last = self.streams.get(stream)
        if last is not None and timestamp <= last:
            return "old or replayed timestamp"
        if last is None and timestamp + int(STALE_NEW_STREAM_S * TICKS_PER_S) < now:
            return "new stream with a stale timestamp"
        if timestamp > now + int(MAX_AHEAD_S * TICKS_PER_S):
            return "timestamp too far in the future"
        self.streams[stream] = timestamp
        return None


def _is_address(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


class Endpoint:
    """One UDP endpoint: its socket, an encoder (signs outgoing), a decoder and a signature check.

    ``target`` is where its messages go until a peer speaks (then they go to the peer: ``remote``). A target
    given by name (``--remote-host mission`` under compose) is looked up by a thread of its own, never by
    ``sendto`` on the sim loop: a name the resolver cannot answer (under Docker, a stopped container's, ~10 s
    a lookup) would stall the vehicle's clock. Until the name resolves, nothing is sent (``unresolved_tx``)."""

    def __init__(self, name: str, bind: tuple[str, int], remote: tuple[str, int], sysid: int, compid: int,
                 signing_key: bytes | None, link_id: int, wall_time_s: float,
                 clock: Callable[[], float] = time.time):
        self.name = name
        self.target = remote
        self.remote: tuple[str, int] | None = remote if _is_address(remote[0]) else None
        self._closed = threading.Event()
        self._remote_lock = threading.Lock()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(bind)
        self.sock.setblocking(False)
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)  # outgoing only
        self.decoder = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)  # no key: we verify
        self.decoder.robust_parsing = True
        self.peer_seen = False
        self.last_rx_wall: float | None = None
        self.signature: SignatureCheck | None = None
        self._clock = clock
        if signing_key is not None:
            s = self.mav.signing
            s.secret_key = signing_key
            s.sign_outgoing = True
            s.link_id = link_id
            s.timestamp = signing_timestamp(wall_time_s)
            self.signature = SignatureCheck(signing_key, self.signing_now)
        if self.remote is None:
            threading.Thread(target=self._resolve, name=f"resolve-{name}", daemon=True).start()

    def _resolve(self) -> None:
        host, port = self.target
        while not self._closed.is_set():
            try:
                info = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
            except OSError as exc:
                log.debug("%s: %s does not resolve: %s", self.name, host, exc)
            else:
                with self._remote_lock:
                    if not self.peer_seen:  # a peer that spoke is answered where it spoke from
                        self.remote = info[0][4][:2]
            self._closed.wait(RESOLVE_EVERY_S)

    def heard_from(self, addr: tuple[str, int], now_wall: float) -> None:
        """A valid message came from ``addr``: answer there from now on (PX4 SITL behaviour)."""
        with self._remote_lock:
            self.remote = addr
            self.peer_seen, self.last_rx_wall = True, now_wall

    def signing_now(self) -> int:
        """Our signing clock: real time, or later if we already sent later timestamps (one tick per message)."""
        s = self.mav.signing
        s.timestamp = max(s.timestamp, signing_timestamp(self._clock()))
        return s.timestamp

    @property
    def local_address(self) -> tuple[str, int]:
        return self.sock.getsockname()

    def close(self) -> None:
        self._closed.set()
        self.sock.close()


class Link:
    """All endpoints of the vehicle; ``recv`` yields (endpoint, message), ``send`` goes to all."""

    def __init__(self, endpoints: list[tuple[str, tuple[str, int], tuple[str, int]]], *, sysid: int = 1,
                 compid: int = 1, signing_key: bytes | None = None, drop_rate: float = 0.0, seed: int = 0,
                 wall_time_s: float = 0.0, clock: Callable[[], float] = time.time):
        if not 0.0 <= drop_rate < 1.0:
            raise ValueError(f"drop rate {drop_rate} must be in [0, 1)")
        self.endpoints = [Endpoint(name, bind, remote, sysid, compid, signing_key, k, wall_time_s, clock)
                          for k, (name, bind, remote) in enumerate(endpoints)]
        self.signing = signing_key is not None
        self.drop_rate = drop_rate
        self._rng = np.random.default_rng(seed + 7919)
        self.stats = LinkStats()
        #: sees each sent message once, with the bytes sent (the GCS endpoint's when it went there): the flight log
        self.tap: Callable[[object, bytes], None] | None = None

    def _drop(self) -> bool:
        return self.drop_rate > 0 and self._rng.random() < self.drop_rate

    def wait(self, timeout_s: float) -> bool:
        """Block until a datagram is readable or ``timeout_s`` passes."""
        r, _, _ = select.select([e.sock for e in self.endpoints], [], [], max(timeout_s, 0.0))
        return bool(r)

    def recv(self, now_wall: float) -> list[tuple[Endpoint, object]]:
        out = []
        for ep in self.endpoints:
            for _ in range(256):  # bounded: never starve the sim loop
                try:
                    data, addr = ep.sock.recvfrom(65535)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError as exc:  # ICMP port unreachable from a previous send, etc.
                    log.debug("%s: recv error %s", ep.name, exc)
                    continue
                if self._drop():
                    self.stats.dropped_rx += 1
                    continue
                out.extend((ep, m) for m in self.receive(ep, data, addr, now_wall))
        return out

    def receive(self, ep: Endpoint, data: bytes, addr: tuple[str, int], now_wall: float) -> list:
        """The accepted messages of one datagram (no socket involved: tests feed datagrams here)."""
        self.stats.rx_packets += 1
        frames, bad = decode_datagram(ep.decoder, data)
        if bad:
            self.stats.bad_data += 1
            log.debug("%s: %d unusable stretch(es) in a %d-byte datagram from %s", ep.name, bad, len(data), addr)
        out = []
        for frame, msg in frames:
            if ep.signature is not None:
                reason = ep.signature.verify(frame)
                if reason is not None:
                    self._refused(ep, msg, reason, addr)
                    continue
            if isinstance(msg, mavlink.MAVLink_unknown):
                self.stats.unknown += 1
                continue
            # answer whoever talks to us (PX4 SITL behaviour), but only once it said something valid:
            # refused or garbage datagrams must not redirect telemetry nor count as a live link
            ep.heard_from(addr, now_wall)
            out.append(msg)
        return out

    def _refused(self, ep: Endpoint, msg, reason: str, addr) -> None:
        self.stats.rejected_signature += 1
        n = self.stats.rejected_signature
        if worth_reporting(n, first=10):  # a flood of forgeries must not flood the log
            log.warning("%s: refused %s from %d/%d at %s: %s (%d refused so far)", ep.name, msg.get_type(),
                        msg.get_srcSystem(), msg.get_srcComponent(), addr, reason, n)

    def send(self, msg, endpoint: Endpoint | None = None) -> None:
        """Pack ``msg`` for each endpoint (its own sequence numbers and signature) and send it; the ``tap`` sees
        the bytes sent to the GCS endpoint, or to the one endpoint a reply went to (what a GCS's log holds)."""
        logged = None
        for ep in [endpoint] if endpoint is not None else self.endpoints:
            if ep.signature is not None:
                ep.signing_now()  # outgoing timestamps follow real time, not just the message count
            try:
                buf = msg.pack(ep.mav)
            except Exception as exc:  # noqa: BLE001 - a bad value must not crash the loop
                log.error("cannot pack %s: %s", msg.get_type(), exc)
                return
            ep.mav.seq = (ep.mav.seq + 1) % 256
            if logged is None or ep.name == "gcs":
                logged = buf
            if self._drop():
                self.stats.dropped_tx += 1
                continue
            remote = ep.remote
            if remote is None:
                self.stats.unresolved_tx += 1
                continue
            try:
                ep.sock.sendto(buf, remote)
                self.stats.tx_packets += 1
            except OSError as exc:
                log.debug("%s: send error %s", ep.name, exc)
        if self.tap is not None and logged is not None:
            self.tap(msg, logged)

    @property
    def last_rx_wall(self) -> float | None:
        times = [e.last_rx_wall for e in self.endpoints if e.last_rx_wall is not None]
        return max(times) if times else None

    def close(self) -> None:
        for ep in self.endpoints:
            ep.close()
