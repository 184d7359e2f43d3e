"""MAVLink 2 over UDP, the way PX4 SITL does it: one socket per endpoint, bound on loopback, sending to
the well-known port (14540 API/offboard, 14550 GCS) and answering whoever last wrote to it.

Also here: MAVLink 2 signing (pymavlink's implementation, key from a file) and fault injection
(``drop_rate``: each datagram in either direction is lost with that probability, seeded).
"""

from __future__ import annotations

import hashlib
import logging
import os
import select
import socket
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")

import numpy as np  # noqa: E402
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

log = logging.getLogger(__name__)

SIGNING_EPOCH_S = 1420070400  # MAVLink signing timestamps count 10 us units since 2015-01-01


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


@dataclass
class LinkStats:
    rx_packets: int = 0
    tx_packets: int = 0
    dropped_rx: int = 0
    dropped_tx: int = 0
    bad_data: int = 0
    rejected_signature: int = 0


class Endpoint:
    """One UDP endpoint with its own MAVLink parser/encoder state."""

    def __init__(self, name: str, bind: tuple[str, int], remote: tuple[str, int], sysid: int, compid: int,
                 signing_key: bytes | None, link_id: int, wall_time_s: float):
        self.name = name
        self.remote = remote
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(bind)
        self.sock.setblocking(False)
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.mav.robust_parsing = True
        self.peer_seen = False
        self.last_rx_wall: float | None = None
        if signing_key is not None:
            s = self.mav.signing
            s.secret_key = signing_key
            s.sign_outgoing = True
            s.link_id = link_id
            s.timestamp = int((max(wall_time_s, SIGNING_EPOCH_S) - SIGNING_EPOCH_S) * 100_000)
            s.allow_unsigned_callback = lambda _mav, _msgid: False

    @property
    def local_address(self) -> tuple[str, int]:
        return self.sock.getsockname()


class Link:
    """All endpoints of the vehicle; ``recv`` yields (endpoint, message), ``send`` goes to all."""

    def __init__(self, endpoints: list[tuple[str, tuple[str, int], tuple[str, int]]], *, sysid: int = 1,
                 compid: int = 1, signing_key: bytes | None = None, drop_rate: float = 0.0, seed: int = 0,
                 wall_time_s: float = 0.0):
        if not 0.0 <= drop_rate < 1.0:
            raise ValueError(f"drop rate {drop_rate} must be in [0, 1)")
        self.endpoints = [Endpoint(name, bind, remote, sysid, compid, signing_key, k, wall_time_s)
                          for k, (name, bind, remote) in enumerate(endpoints)]
        self.signing = signing_key is not None
        self.drop_rate = drop_rate
        self._rng = np.random.default_rng(seed + 7919)
        self.stats = LinkStats()

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
                self.stats.rx_packets += 1
                try:
                    msgs = ep.mav.parse_buffer(data) or []
                except Exception as exc:  # noqa: BLE001 - a malformed datagram must never stop the vehicle
                    log.warning("%s: unparsable datagram (%s)", ep.name, exc)
                    ep.mav.buf, ep.mav.buf_index = bytearray(), 0
                    self.stats.bad_data += 1
                    continue
                for m in msgs:
                    if m.get_type() == "BAD_DATA":
                        reason = getattr(m, "reason", "")
                        if "signature" in str(reason).lower():
                            self.stats.rejected_signature += 1
                            log.warning("%s: refused a message with a missing or wrong signature from %s",
                                        ep.name, addr)
                        else:
                            self.stats.bad_data += 1
                        continue
                    # answer whoever talks to us (PX4 SITL behaviour), but only once it said something
                    # valid: refused or garbage datagrams must not redirect the vehicle's telemetry
                    ep.remote = addr
                    ep.peer_seen, ep.last_rx_wall = True, now_wall
                    out.append((ep, m))
        return out

    def send(self, msg, endpoint: Endpoint | None = None) -> None:
        for ep in [endpoint] if endpoint is not None else self.endpoints:
            try:
                buf = msg.pack(ep.mav)
            except Exception as exc:  # noqa: BLE001 - a bad value must not crash the loop
                log.error("cannot pack %s: %s", msg.get_type(), exc)
                return
            ep.mav.seq = (ep.mav.seq + 1) % 256
            if self._drop():
                self.stats.dropped_tx += 1
                continue
            try:
                ep.sock.sendto(buf, ep.remote)
                self.stats.tx_packets += 1
            except OSError as exc:
                log.debug("%s: send error %s", ep.name, exc)

    @property
    def last_rx_wall(self) -> float | None:
        times = [e.last_rx_wall for e in self.endpoints if e.last_rx_wall is not None]
        return max(times) if times else None

    def close(self) -> None:
        for ep in self.endpoints:
            ep.sock.close()
