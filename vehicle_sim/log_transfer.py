"""The MAVLink log protocol (https://mavlink.io/en/services/log.html) serving the vehicle's flight log.

LOG_REQUEST_LIST -> one LOG_ENTRY per log in the asked id range (the one log of this boot, id 0, its size and
UTC start time: the vehicle's ULog, as PX4 lists its .ulg files; with no log at all one LOG_ENTRY with num_logs 0,
as the protocol asks). LOG_REQUEST_DATA ->
LOG_DATA packets of 90 bytes from ``ofs`` for ``count`` bytes (clipped to the log's end; an offset at or past the
end gets one LOG_DATA with count 0), handed out in order by ``pending`` so that a 46 kB request (MAVSDK asks 512
packets at a time) is paced instead of overflowing the client's socket. LOG_REQUEST_END stops a transfer.
LOG_ERASE is ignored: nothing recorded is deleted (PX4 would erase its SD card's logs)."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from typing import Protocol

from pymavlink.dialects.v20 import common as M

log = logging.getLogger(__name__)

CHUNK = 90  # LOG_DATA's data field


class ServedLog(Protocol):
    """A log the protocol can serve (``px4_logger.Px4Logger``, ``flight_log.FlightLog``)."""

    boot_wall_s: float

    def size(self) -> int: ...

    def read(self, offset: int, count: int) -> bytes: ...


class LogServer:
    """Answers the log protocol for one log."""

    def __init__(self, flight_log: ServedLog | None):
        self.log = flight_log
        self._transfer: Iterator | None = None

    def handle(self, msg) -> list:
        """Immediate replies to one message (LOG_ENTRYs); data goes out through ``pending``."""
        kind = msg.get_type()
        if kind == "LOG_REQUEST_LIST":
            if self.log is None:
                return [M.MAVLink_log_entry_message(0, 0, 0, 0, 0)]
            if msg.start > 0 or msg.end < 0:
                return []
            return [M.MAVLink_log_entry_message(0, 1, 0, int(self.log.boot_wall_s), self.log.size())]
        if kind == "LOG_REQUEST_DATA":
            if self.log is None or msg.id != 0:
                log.info("LOG_REQUEST_DATA for unknown log %d ignored", msg.id)
                return []
            self._transfer = self._data(int(msg.ofs), int(msg.count))
            return []
        if kind == "LOG_REQUEST_END":
            self._transfer = None
        elif kind == "LOG_ERASE":
            log.info("LOG_ERASE ignored: the flight log is kept")
        return []

    def _data(self, ofs: int, count: int) -> Iterator:
        end = min(ofs + count, self.log.size())
        if ofs >= end:
            yield M.MAVLink_log_data_message(0, ofs, 0, [0] * CHUNK)
            return
        while ofs < end:
            chunk = self.log.read(ofs, min(CHUNK, end - ofs))
            yield M.MAVLink_log_data_message(0, ofs, len(chunk), list(chunk) + [0] * (CHUNK - len(chunk)))
            ofs += len(chunk)

    def pending(self, n: int) -> list:
        """Up to ``n`` LOG_DATA of the current transfer, in order."""
        out = []
        while self._transfer is not None and len(out) < n:
            m = next(self._transfer, None)
            if m is None:
                self._transfer = None
            else:
                out.append(m)
        return out
