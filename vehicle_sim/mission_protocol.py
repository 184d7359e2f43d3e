"""The MAVLink mission protocol, vehicle side: upload, download, clear, set-current.

A message-driven state machine: ``handle(msg, now)`` and ``poll(now)`` return the MAVLink messages to
send back (pymavlink message objects; the link packs them). Time is the link's clock (the peer is a
real-time GCS with its own timeouts). Three lists are kept, one per mission type, each with the same
transfer protocol: MISSION (0), FENCE (1: NAV_FENCE_* polygon vertices and circles) and RALLY (2:
NAV_RALLY_POINT). A list is checked item by item (``validate``) and, once complete, as a whole
(``validate_list``: e.g. a polygon's vertex count), before it replaces the stored one.

Upload: MISSION_COUNT -> MISSION_REQUEST_INT(seq) ... MISSION_ITEM_INT -> MISSION_ACK. A request
whose item does not arrive within ``retry_s`` is sent again, up to ``max_retries`` times, then the
upload is cancelled (MISSION_ACK OPERATION_CANCELLED). A repeated MISSION_COUNT restarts the upload;
a repeated last item after completion is re-acknowledged (the GCS lost our ACK). The final ACK is sent
once, as PX4 does: MAVSDK's upload takes *any* MISSION_ACK ACCEPTED as its own, whatever its
mission_type, and one arriving before its last item is a PROTOCOL_ERROR
(``MavlinkMissionTransferClient::UploadWorkItem::process_mission_ack``), so a late copy of a fence
upload's ACK broke the rally upload that followed it on a loaded machine. MAVSDK does not resend the last
item when the final ACK is lost (it times out); radseek's client tries such a transfer again
(``mission.client.mission_upload.MissionControl.transfer``). Requests are re-sent after
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
# DO items accepted in a mission that do not move the vehicle (camera/gimbal/ROI: a GPS-denied survey
# drone has none to drive, but MAVSDK's Mission plugin and QGC plans emit them): stored, listed, skipped.
PASSIVE_DO_COMMANDS = {
    M.MAV_CMD_DO_SET_ROI_NONE, M.MAV_CMD_DO_SET_CAM_TRIGG_DIST, M.MAV_CMD_DO_MOUNT_CONTROL,
    M.MAV_CMD_DO_DIGICAM_CONTROL, M.MAV_CMD_IMAGE_START_CAPTURE, M.MAV_CMD_IMAGE_STOP_CAPTURE,
    M.MAV_CMD_VIDEO_START_CAPTURE, M.MAV_CMD_VIDEO_STOP_CAPTURE, M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
    M.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, M.MAV_CMD_DO_SET_SERVO, M.MAV_CMD_DO_SET_RELAY,
}
# DO items that point the vehicle: ROI at a location (yaw towards it at later waypoints without a yaw)
ROI_COMMANDS = {M.MAV_CMD_DO_SET_ROI_LOCATION, M.MAV_CMD_DO_SET_ROI}
SUPPORTED_COMMANDS = {
    M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LOITER_TIME, M.MAV_CMD_NAV_RETURN_TO_LAUNCH, M.MAV_CMD_NAV_LAND,
    M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_DELAY, M.MAV_CMD_DO_CHANGE_SPEED, M.MAV_CMD_NAV_LOITER_UNLIM,
    *PASSIVE_DO_COMMANDS, *ROI_COMMANDS,
}
FENCE_COMMANDS = {M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
                  M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION,
                  M.MAV_CMD_NAV_FENCE_RETURN_POINT}
RALLY_COMMANDS = {M.MAV_CMD_NAV_RALLY_POINT}
MISSION_TYPES = (M.MAV_MISSION_TYPE_MISSION, M.MAV_MISSION_TYPE_FENCE, M.MAV_MISSION_TYPE_RALLY)
POSITIONAL_COMMANDS = {M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LOITER_TIME, M.MAV_CMD_NAV_LAND, M.MAV_CMD_NAV_TAKEOFF,
                       M.MAV_CMD_NAV_LOITER_UNLIM, M.MAV_CMD_DO_SET_ROI_LOCATION, *FENCE_COMMANDS, *RALLY_COMMANDS}
# items whose z is an altitude the vehicle flies to (a NaN z elsewhere, e.g. DO_CHANGE_SPEED's, means unused)
ALTITUDE_COMMANDS = {M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LOITER_TIME, M.MAV_CMD_NAV_TAKEOFF,
                     M.MAV_CMD_NAV_LOITER_UNLIM, M.MAV_CMD_NAV_RALLY_POINT}
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
    mission_type: int = 0  # MAV_MISSION_TYPE: 0 mission, 1 fence, 2 rally

    @classmethod
    def from_msg(cls, msg) -> MissionItem:
        if msg.get_type() == "MISSION_ITEM":  # float lat/lon variant
            x = int(round(msg.x * 1e7)) if msg.frame in GLOBAL_FRAMES else int(msg.x)
            y = int(round(msg.y * 1e7)) if msg.frame in GLOBAL_FRAMES else int(msg.y)
        else:
            x, y = int(msg.x), int(msg.y)
        return cls(int(msg.seq), int(msg.frame), int(msg.command), float(msg.param1), float(msg.param2),
                   float(msg.param3), float(msg.param4), x, y, float(msg.z), int(msg.autocontinue),
                   int(getattr(msg, "mission_type", 0)))


# item validator: returns MAV_MISSION_ACCEPTED or the MAV_MISSION_RESULT refusing it
Validator = Callable[[MissionItem], int]


def basic_validate(item: MissionItem) -> int:
    """Checks that need no geography: command (for the item's mission type), frame, parameter sanity."""
    allowed = {M.MAV_MISSION_TYPE_MISSION: SUPPORTED_COMMANDS, M.MAV_MISSION_TYPE_FENCE: FENCE_COMMANDS,
               M.MAV_MISSION_TYPE_RALLY: RALLY_COMMANDS}.get(item.mission_type, set())
    if item.command not in allowed:
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
    if item.command in (M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION):
        if not math.isfinite(item.param1) or item.param1 < 3 or item.param1 != int(item.param1):
            return M.MAV_MISSION_INVALID_PARAM1  # vertex count: a polygon needs 3 or more
    if item.command in (M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION):
        if not math.isfinite(item.param1) or item.param1 < 0:
            return M.MAV_MISSION_INVALID_PARAM1  # radius (0 = MAVSDK's "no circle": kept, encloses nothing)
    if not math.isfinite(item.z) and item.command in ALTITUDE_COMMANDS:
        return M.MAV_MISSION_INVALID_PARAM7
    return M.MAV_MISSION_ACCEPTED


# whole-list check once an upload is complete: MAV_MISSION_ACCEPTED or the result refusing the list
ListValidator = Callable[[list[MissionItem], int], int]


def _accept_list(items: list[MissionItem], mission_type: int) -> int:
    return M.MAV_MISSION_ACCEPTED


@dataclass
class _Transfer:
    partner: tuple[int, int]
    count: int
    items: list[MissionItem]
    next_seq: int
    last_sent: float
    retries: int = 0
    mission_type: int = 0


class MissionProtocol:
    """Holds the vehicle's mission, fence and rally lists and runs the transfer protocol."""

    def __init__(self, validate: Validator = basic_validate, *, max_items: int = 500, retry_s: float = 0.2,
                 max_retries: int = 15, sysid: int = 1, compid: int = 1,
                 validate_list: ListValidator = _accept_list):
        self.validate, self.validate_list = validate, validate_list
        self.max_items, self.retry_s, self.max_retries = max_items, retry_s, max_retries
        self.sysid, self.compid = sysid, compid
        self.lists: dict[int, list[MissionItem]] = {t: [] for t in MISSION_TYPES}
        self.mission_id = 0  # bumped on every change (opaque id reported in MISSION_CURRENT)
        self.changed = False  # mission list set on upload/clear; the vehicle resets it when it has reacted
        self.changed_types: set[int] = set()  # fence/rally lists changed; the vehicle empties it when it reacted
        self._upload: _Transfer | None = None
        self._last_done: tuple[tuple[int, int], int, int] | None = None  # (partner, count, type) of the last upload

    @property
    def items(self) -> list[MissionItem]:
        """The mission (type 0) items."""
        return self.lists[M.MAV_MISSION_TYPE_MISSION]

    @items.setter
    def items(self, value: list[MissionItem]) -> None:
        self.lists[M.MAV_MISSION_TYPE_MISSION] = value

    # -- helpers -------------------------------------------------------------------------------
    def _ack(self, partner: tuple[int, int], result: int, mission_type: int = 0):
        return M.MAVLink_mission_ack_message(partner[0], partner[1], result, mission_type)

    def _request(self, partner: tuple[int, int], seq: int, mission_type: int = 0):
        return M.MAVLink_mission_request_int_message(partner[0], partner[1], seq, mission_type)

    def _item_msg(self, partner: tuple[int, int], item: MissionItem, current: int, as_int: bool):
        cur = 1 if item.seq == current and item.mission_type == M.MAV_MISSION_TYPE_MISSION else 0
        if as_int:
            return M.MAVLink_mission_item_int_message(
                partner[0], partner[1], item.seq, item.frame, item.command, cur, item.autocontinue,
                item.param1, item.param2, item.param3, item.param4, item.x, item.y, item.z, item.mission_type)
        glob = item.frame in GLOBAL_FRAMES
        return M.MAVLink_mission_item_message(
            partner[0], partner[1], item.seq, item.frame, item.command, cur, item.autocontinue,
            item.param1, item.param2, item.param3, item.param4,
            item.x / 1e7 if glob else float(item.x), item.y / 1e7 if glob else float(item.y), item.z,
            item.mission_type)

    @property
    def uploading(self) -> bool:
        return self._upload is not None

    def _store(self, mtype: int, items: list[MissionItem]) -> None:
        self.lists[mtype] = items
        if mtype == M.MAV_MISSION_TYPE_MISSION:
            self.mission_id += 1
            self.changed = True
        else:
            self.changed_types.add(mtype)

    def clear(self, mtype: int = M.MAV_MISSION_TYPE_MISSION) -> None:
        for t in (MISSION_TYPES if mtype == M.MAV_MISSION_TYPE_ALL else (mtype,)):
            self._store(t, [])

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
            if mtype not in self.lists:
                return [self._ack(partner, M.MAV_MISSION_UNSUPPORTED, mtype)]
            return [M.MAVLink_mission_count_message(partner[0], partner[1], len(self.lists[mtype]), mtype)]
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            items = self.lists.get(mtype)
            if items is None or not 0 <= msg.seq < len(items):
                return [self._ack(partner, M.MAV_MISSION_INVALID_SEQUENCE, mtype)]
            return [self._item_msg(partner, items[msg.seq], current, kind == "MISSION_REQUEST_INT")]
        if kind == "MISSION_CLEAR_ALL":
            if mtype not in self.lists and mtype != M.MAV_MISSION_TYPE_ALL:
                return [self._ack(partner, M.MAV_MISSION_UNSUPPORTED, mtype)]
            if self._upload is not None and (mtype in (self._upload.mission_type, M.MAV_MISSION_TYPE_ALL)):
                self._upload = None
            self.clear(mtype)
            return [self._ack(partner, M.MAV_MISSION_ACCEPTED, mtype)]
        if kind == "MISSION_ACK":
            return []  # end of a download; nothing to do
        return []

    def _on_count(self, msg, partner, mtype, now) -> list:
        if mtype not in self.lists:
            return [self._ack(partner, M.MAV_MISSION_UNSUPPORTED, mtype)]
        if self._upload is not None and self._upload.partner != partner:
            return [self._ack(partner, M.MAV_MISSION_DENIED, mtype)]  # busy with another GCS
        if msg.count > self.max_items:
            return [self._ack(partner, M.MAV_MISSION_NO_SPACE, mtype)]
        if msg.count == 0:
            self._upload = None
            self.clear(mtype)
            return [self._ack(partner, M.MAV_MISSION_ACCEPTED, mtype)]
        self._upload = _Transfer(partner, int(msg.count), [], 0, now, mission_type=mtype)
        self._last_done = None
        return [self._request(partner, 0, mtype)]

    def _on_item(self, msg, partner, now) -> list:
        mtype = getattr(msg, "mission_type", 0)
        up = self._upload
        if up is None:
            if self._last_done == (partner, msg.seq + 1, mtype):  # our final ACK was lost: say it again
                return [self._ack(partner, M.MAV_MISSION_ACCEPTED, mtype)]
            log.info("mission item %d from %s outside an upload: ignored", msg.seq, partner)
            return []
        if partner != up.partner or mtype != up.mission_type:
            return [self._ack(partner, M.MAV_MISSION_DENIED, mtype)]
        if msg.seq != up.next_seq:
            if msg.seq < up.next_seq:
                return []  # a duplicate of an item we have: our next request is on its way
            up.last_sent = now
            return [self._request(partner, up.next_seq, mtype)]  # out of order: ask again for the one we need
        try:
            item = replace(MissionItem.from_msg(msg), seq=msg.seq)
            result = self.validate(item)
        except (ValueError, TypeError, OverflowError) as exc:
            log.warning("malformed mission item %d: %s", msg.seq, exc)
            result = M.MAV_MISSION_INVALID
        if result != M.MAV_MISSION_ACCEPTED:
            log.warning("mission item %d (cmd %d, type %d) refused: result %d", msg.seq, msg.command, mtype, result)
            self._upload = None
            return [self._ack(partner, result, mtype)]
        up.items.append(item)
        up.next_seq += 1
        up.retries = 0
        up.last_sent = now
        if up.next_seq < up.count:
            return [self._request(partner, up.next_seq, mtype)]
        self._upload = None
        result = self.validate_list(up.items, mtype)
        if result != M.MAV_MISSION_ACCEPTED:
            log.warning("list of %d items (type %d) refused: result %d", up.count, mtype, result)
            return [self._ack(partner, result, mtype)]
        self._store(mtype, up.items)
        self._last_done = (partner, up.count, mtype)
        log.info("list of %d items (type %d) accepted", len(up.items), mtype)
        return [self._ack(partner, M.MAV_MISSION_ACCEPTED, mtype)]

    def poll(self, now: float) -> list:
        """Retransmit a request whose answer is late; cancel a stalled upload."""
        up = self._upload
        if up is None or now - up.last_sent < self.retry_s:
            return []
        if up.retries >= self.max_retries:
            log.warning("mission upload timed out waiting for item %d", up.next_seq)
            self._upload = None
            return [self._ack(up.partner, M.MAV_MISSION_OPERATION_CANCELLED, up.mission_type)]
        up.retries += 1
        up.last_sent = now
        return [self._request(up.partner, up.next_seq, up.mission_type)]
