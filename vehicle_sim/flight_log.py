"""The vehicle's own flight log: every MAVLink message it sends, recorded from boot as a telemetry log (.tlog).

PX4 writes a ULog per flight to its SD card (``/fs/microsd/log/<date>/<time>.ulg``: ``px4_logger``); beside it
the mock vehicle records what it tells the world, in the format MAVProxy, QGroundControl and
pymavlink (``mavutil.mavlink_connection(path)``, ``mavlogdump.py``) read: each message as an 8-byte big-endian
microsecond timestamp followed by the MAVLink 2 frame as the link sent it (the bytes sent to the GCS endpoint,
or to the one endpoint a reply went to: sequence numbers and signatures are those a ground station received).
The timestamp is the boot's wall clock plus the simulated time, so a log of a sped-up flight spans the simulated
flight. One log per boot (PX4's SDLOG_MODE 2,
"from boot until shutdown"), served while it grows by MAVLink FTP (``mavftp``; the log protocol serves the
ULog, as PX4). The transfers themselves (FILE_TRANSFER_PROTOCOL, LOG_DATA, LOG_ENTRY) are not recorded,
so a download never feeds the file it reads. Bounded like a card: past ``max_bytes`` recording stops, and what
is recorded stays (``full`` says so)."""

from __future__ import annotations

import struct
import time

NOT_LOGGED = frozenset({"FILE_TRANSFER_PROTOCOL", "LOG_DATA", "LOG_ENTRY"})
DEFAULT_MAX_BYTES = 64 * 1024 * 1024


class FlightLog:
    """The growing .tlog of one boot, in memory."""

    def __init__(self, boot_wall_s: float | None = None, max_bytes: int = DEFAULT_MAX_BYTES):
        self.boot_wall_s = time.time() if boot_wall_s is None else boot_wall_s
        self.max_bytes = max_bytes
        self.full = False
        self._data = bytearray()

    @property
    def name(self) -> str:
        """PX4's log file naming (UTC date folder, time of day) with the .tlog extension of its format."""
        return time.strftime("%Y-%m-%d/%H_%M_%S.tlog", time.gmtime(self.boot_wall_s))

    def record(self, msg, frame: bytes, sim_t: float) -> None:
        """Append one sent message, ``frame`` the bytes the link sent, at sim time ``sim_t`` (s since boot)."""
        if self.full or msg.get_type() in NOT_LOGGED:
            return
        if len(self._data) + 8 + len(frame) > self.max_bytes:
            self.full = True
            return
        self._data += struct.pack(">Q", int((self.boot_wall_s + sim_t) * 1e6)) + frame

    def size(self) -> int:
        return len(self._data)

    def read(self, offset: int, count: int) -> bytes:
        """Up to ``count`` bytes from ``offset`` (empty at or past the end)."""
        return bytes(self._data[offset:offset + count])
