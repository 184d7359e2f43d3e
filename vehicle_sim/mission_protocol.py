"""The MAVLink mission protocol, vehicle side: upload, download, clear, set-current.

A message-driven state machine: ``handle(msg, now)`` and ``poll(now)`` return the MAVLink messages to
send back (pymavlink message objects; the link packs them). Time is the link's clock (the peer is a
real-time GCS with its own timeouts). Only the MISSION type (0) holds items; fence and rally uploads
are refused with MAV_MISSION_UNSUPPORTED and download as empty.

Upload: MISSION_COUNT -> MISSION_REQUEST_INT(seq) ... MISSION_ITEM_INT -> MISSION_ACK. A request
whose item does not arrive within ``retry_s`` is sent again, up to ``max_retries`` times, then the
upload is cancelled (MISSION_ACK OPERATION_CANCELLED). A repeated MISSION_COUNT restarts the upload;
a repeated last item after completion is re-acknowledged (the GCS lost our ACK). Because MAVSDK does
*not* resend the last item when the final ACK is lost (it just times out), the final ACK is sent
``final_ack_copies`` times back to back: on a link losing 10 % of datagrams independently, 3 copies cut
the chance of a spurious upload timeout from 1 in 10 to 1 in 1000. Requests are re-sent after
``retry_s`` = 0.2 s, faster than MAVSDK's own 0.5 s timeout, so a lost item costs MAVSDK one retry
rather than two (it gives up after 5).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace

from pymavlink.dialects.v20 import common as mavlink

log = logging.getLogger(__name__)

M = mavlink
SUPPORTED_COMMANDS = {
    M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LOITER_TIME, M.MAV_CMD_NAV_RETURN_TO_LAUNCH, M.MAV_CMD_NAV_LAND,
    M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_DELAY, M.MAV_CMD_DO_CHANGE_SPEED,
}
POSITIONAL_COMMANDS = {M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LOITER_TIME, M.MAV_CMD_NAV_LAND, M.MAV_CMD_NAV_TAKEOFF}
GLOBAL_FRAMES = {M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_INT,
                 M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
SUPPORTED_FRAMES = GLOBAL_FRAMES | {M.MAV_FRAME_MISSION}


@dataclass(frozen=True)
class MissionItem:
    """One item exactly as MISSION_ITEM_INT carries it (x, y = degE7 in global frames)."""

    seq: int
    frame: int
    command: int
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    x: int = 0
    y: int = 0
    z: float = 0.0
    autocontinue: int = 1

    @classmethod
    def from_msg(cls, msg) -> MissionItem:
        if msg.get_type() == "MISSION_ITEM":  # float lat/lon variant
            x = int(round(msg.x * 1e7)) if msg.frame in GLOBAL_FRAMES else int(msg.x)
            y = int(round(msg.y * 1e7)) if msg.frame in GLOBAL_FRAMES else int(msg.y)
        else:
            x, y = int(msg.x), int(msg.y)
        return cls(int(msg.seq), int(msg.frame), int(msg.command), float(msg.param1), float(msg.param2),
                   float(msg.param3), float(msg.param4), x, y, float(msg.z), int(msg.autocontinue))


# item validator: returns MAV_MISSION_ACCEPTED or the MAV_MISSION_RESULT refusing it
Validator = Callable[[MissionItem], int]


def basic_validate(item: MissionItem) -> int:
    """Checks that need no geography: command, frame, parameter sanity."""
    if item.command not in SUPPORTED_COMMANDS:
        return M.MAV_MISSION_UNSUPPORTED
    if item.frame not in SUPPORTED_FRAMES:
        return M.MAV_MISSION_UNSUPPORTED_FRAME
    if item.command in POSITIONAL_COMMANDS and item.frame == M.MAV_FRAME_MISSION:
        return M.MAV_MISSION_UNSUPPORTED_FRAME
    if item.command in (M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LOITER_TIME, M.MAV_CMD_NAV_DELAY):
        if not math.isfinite(item.param1) or item.param1 < 0 or item.param1 > 86400:
            return M.MAV_MISSION_INVALID_PARAM1
    if item.command == M.MAV_CMD_DO_CHANGE_SPEED and math.isfinite(item.param2) and item.param2 > 20:
        return M.MAV_MISSION_INVALID_PARAM2
    if not math.isfinite(item.z) and item.command != M.MAV_CMD_NAV_LAND:
        return M.MAV_MISSION_INVALID_PARAM7
    return M.MAV_MISSION_ACCEPTED


@dataclass
class _Transfer:
    partner: tuple[int, int]
    count: int
    items: list[MissionItem]
    next_seq: int
    last_sent: float
    retries: int = 0


class MissionProtocol:
    """Holds the vehicle's mission and runs the transfer protocol."""

    def __init__(self, validate: Validator = basic_validate, *, max_items: int = 500, retry_s: float = 0.2,
                 max_retries: int = 15, final_ack_copies: int = 3, sysid: int = 1, compid: int = 1):
        self.final_ack_copies = max(1, final_ack_copies)
        self.validate = validate
        self.max_items, self.retry_s, self.max_retries = max_items, retry_s, max_retries
        self.sysid, self.compid = sysid, compid
        self.items: list[MissionItem] = []
        self.mission_id = 0  # bumped on every change (opaque id reported in MISSION_CURRENT)
        self.changed = False  # set on upload/clear; the vehicle resets it when it has reacted
        self._upload: _Transfer | None = None
        self._last_done: tuple[tuple[int, int], int] | None = None  # (partner, count) of the last upload

    # -- helpers -------------------------------------------------------------------------------
    def _ack(self, partner: tuple[int, int], result: int, mission_type: int = 0):
        return M.MAVLink_mission_ack_message(partner[0], partner[1], result, mission_type)

    def _request(self, partner: tuple[int, int], seq: int):
        return M.MAVLink_mission_request_int_message(partner[0], partner[1], seq, M.MAV_MISSION_TYPE_MISSION)

    def _item_msg(self, partner: tuple[int, int], item: MissionItem, current: int, as_int: bool):
        cur = 1 if item.seq == current else 0
        if as_int:
            return M.MAVLink_mission_item_int_message(
                partner[0], partner[1], item.seq, item.frame, item.command, cur, item.autocontinue,
                item.param1, item.param2, item.param3, item.param4, item.x, item.y, item.z,
                M.MAV_MISSION_TYPE_MISSION)
        glob = item.frame in GLOBAL_FRAMES
        return M.MAVLink_mission_item_message(
            partner[0], partner[1], item.seq, item.frame, item.command, cur, item.autocontinue,
            item.param1, item.param2, item.param3, item.param4,
            item.x / 1e7 if glob else float(item.x), item.y / 1e7 if glob else float(item.y), item.z,
            M.MAV_MISSION_TYPE_MISSION)

    @property
    def uploading(self) -> bool:
        return self._upload is not None

    def clear(self) -> None:
        self.items = []
        self.mission_id += 1
        self.changed = True

    # -- protocol ------------------------------------------------------------------------------
    def handle(self, msg, now: float, current: int = 0) -> list:
        """React to one MISSION_* message addressed to us; returns replies."""
        kind = msg.get_type()
        partner = (msg.get_srcSystem(), msg.get_srcComponent())
        mtype = getattr(msg, "mission_type", 0)
        if kind == "MISSION_COUNT":
            return self._on_count(msg, partner, mtype, now)
        if kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            return self._on_item(msg, partner, now)
        if kind == "MISSION_REQUEST_LIST":
            n = len(self.items) if mtype == M.MAV_MISSION_TYPE_MISSION else 0
            return [M.MAVLink_mission_count_message(partner[0], partner[1], n, mtype)]
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            if mtype != M.MAV_MISSION_TYPE_MISSION or not 0 <= msg.seq < len(self.items):
                return [self._ack(partner, M.MAV_MISSION_INVALID_SEQUENCE, mtype)]
            return [self._item_msg(partner, self.items[msg.seq], current, kind == "MISSION_REQUEST_INT")]
        if kind == "MISSION_CLEAR_ALL":
            if mtype != M.MAV_MISSION_TYPE_MISSION and mtype != M.MAV_MISSION_TYPE_ALL:
                return [self._ack(partner, M.MAV_MISSION_ACCEPTED, mtype)]  # nothing stored: already clear
            self._upload = None
            self.clear()
            return [self._ack(partner, M.MAV_MISSION_ACCEPTED, mtype)]
        if kind == "MISSION_ACK":
            return []  # end of a download; nothing to do
        return []

    def _on_count(self, msg, partner, mtype, now) -> list:
        if mtype != M.MAV_MISSION_TYPE_MISSION:
            return [self._ack(partner, M.MAV_MISSION_UNSUPPORTED, mtype)]
        if self._upload is not None and self._upload.partner != partner:
            return [self._ack(partner, M.MAV_MISSION_DENIED, mtype)]  # busy with another GCS
        if msg.count > self.max_items:
            return [self._ack(partner, M.MAV_MISSION_NO_SPACE)]
        if msg.count == 0:
            self._upload = None
            self.clear()
            return [self._ack(partner, M.MAV_MISSION_ACCEPTED)]
        self._upload = _Transfer(partner, int(msg.count), [], 0, now)
        self._last_done = None
        return [self._request(partner, 0)]

    def _on_item(self, msg, partner, now) -> list:
        mtype = getattr(msg, "mission_type", 0)
        up = self._upload
        if up is None:
            if self._last_done == (partner, msg.seq + 1):  # our final ACK was lost: say it again
                return [self._ack(partner, M.MAV_MISSION_ACCEPTED)]
            log.info("mission item %d from %s outside an upload: ignored", msg.seq, partner)
            return []
        if partner != up.partner or mtype != M.MAV_MISSION_TYPE_MISSION:
            return [self._ack(partner, M.MAV_MISSION_DENIED, mtype)]
        if msg.seq != up.next_seq:
            if msg.seq < up.next_seq:
                return []  # a duplicate of an item we have: our next request is on its way
            up.last_sent = now
            return [self._request(partner, up.next_seq)]  # out of order: ask again for the one we need
        try:
            item = replace(MissionItem.from_msg(msg), seq=msg.seq)
            result = self.validate(item)
        except (ValueError, TypeError, OverflowError) as exc:
            log.warning("malformed mission item %d: %s", msg.seq, exc)
            result = M.MAV_MISSION_INVALID
        if result != M.MAV_MISSION_ACCEPTED:
            log.warning("mission item %d (cmd %d) refused: result %d", msg.seq, msg.command, result)
            self._upload = None
            return [self._ack(partner, result)]
        up.items.append(item)
        up.next_seq += 1
        up.retries = 0
        up.last_sent = now
        if up.next_seq < up.count:
            return [self._request(partner, up.next_seq)]
        self.items = up.items
        self.mission_id += 1
        self.changed = True
        self._upload = None
        self._last_done = (partner, up.count)
        log.info("mission of %d items accepted", len(self.items))
        return [self._ack(partner, M.MAV_MISSION_ACCEPTED)] * self.final_ack_copies

    def poll(self, now: float) -> list:
        """Retransmit a request whose answer is late; cancel a stalled upload."""
        up = self._upload
        if up is None or now - up.last_sent < self.retry_s:
            return []
        if up.retries >= self.max_retries:
            log.warning("mission upload timed out waiting for item %d", up.next_seq)
            self._upload = None
            return [self._ack(up.partner, M.MAV_MISSION_OPERATION_CANCELLED)]
        up.retries += 1
        up.last_sent = now
        return [self._request(up.partner, up.next_seq)]
