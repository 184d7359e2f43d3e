"""Missions through MAVSDK's mission_raw plugin: dwell points -> raw MISSION_ITEM_INTs, upload,
start, replace the remaining mission in flight, and end a dwell early.

How a dwell point ends (the dwell time is decided in flight from the histogram stream): each dwell
point is a NAV_WAYPOINT whose hold time (param1) is the *longest* dwell allowed. When the dwell
controller has counted enough, the client calls ``end_dwell()``, which sets the current mission item
to the next one (MAV_CMD_DO_SET_MISSION_CURRENT): the vehicle stops holding and flies on at once. If
the link drops, the vehicle still leaves after the maximum hold: the mission never stalls. After every
dwell the planner's new points replace the rest of the mission (``replace_remaining``): the new list
is uploaded and the vehicle continues with its first item. Standard mission items only, so PX4 and
ArduPilot fly the same missions.
"""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass

from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync
from mavsdk.plugins.mission_raw import MissionItem, MissionRawError

from mission.client.connection import Connection
from mission.client.retry import retry_on_timeout
from radseek.coordinates import Home, enu_to_geodetic, yaw_enu_to_ned

MAV_FRAME_MISSION = 2
MAV_FRAME_GLOBAL_RELATIVE_ALT_INT = 6
MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_TAKEOFF = 22




class MissionFailed(Exception):
    """An upload/start/set-current the vehicle refused; ``result`` is MAVSDK's MissionRawResult name."""

    def __init__(self, call: str, result: str):
        super().__init__(f"{call}: {result}")
        self.call, self.result = call, result


@dataclass(frozen=True)
class DwellPoint:
    """A place to measure: local ENU m, yaw rad CCW from east (detector axis), max dwell s."""

    x: float
    y: float
    z: float
    yaw: float | None = None
    max_dwell_s: float = 60.0


def waypoint(seq: int, home: Home, x: float, y: float, z: float, hold_s: float = 0.0,
             yaw: float | None = None) -> MissionItem:
    lat, lon, _ = enu_to_geodetic(home, (x, y, z))
    yaw_deg = math.nan if yaw is None else math.degrees(yaw_enu_to_ned(yaw))
    return MissionItem(seq, MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, MAV_CMD_NAV_WAYPOINT, 0, 1, float(hold_s), 0.0, 0.0,
                       yaw_deg, int(round(lat * 1e7)), int(round(lon * 1e7)), float(z), 0)


def build_items(points: list[DwellPoint], home: Home, *, takeoff_alt: float | None = None,
                finish: str = "none") -> list[MissionItem]:
    """Mission items: optional takeoff, one hold-waypoint per dwell point, then ``finish``
    ("none" = hover at the last point, "land", or "rtl")."""
    items: list[MissionItem] = []
    if takeoff_alt is not None:
        lat, lon, _ = enu_to_geodetic(home, (0.0, 0.0, 0.0))
        items.append(MissionItem(0, MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, MAV_CMD_NAV_TAKEOFF, 0, 1, 0.0, 0.0, 0.0,
                                 math.nan, int(round(lat * 1e7)), int(round(lon * 1e7)), float(takeoff_alt), 0))
    for p in points:
        items.append(waypoint(len(items), home, p.x, p.y, p.z, p.max_dwell_s, p.yaw))
    if finish == "land":
        items.append(MissionItem(len(items), MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, MAV_CMD_NAV_LAND, 0, 1, 0.0, 0.0,
                                 0.0, math.nan, 0, 0, 0.0, 0))
    elif finish == "rtl":
        items.append(MissionItem(len(items), MAV_FRAME_MISSION, MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 1, 0.0, 0.0, 0.0,
                                 0.0, 0, 0, 0.0, 0))
    elif finish != "none":
        raise ValueError(f"finish must be none, land or rtl, got {finish!r}")
    if items:
        items[0].current = 1
    return items


class MissionControl:
    def __init__(self, conn: Connection):
        self._conn = conn
        self._mr = MissionRawAsync(conn.system)
        self.items: list[MissionItem] = []

    async def _do(self, call: str, coro):
        try:
            return await coro
        except MissionRawError as exc:
            raise MissionFailed(call, exc.result.name) from None

    async def retried(self, call: str, start) -> object:
        """An idempotent call (``start()`` makes the MAVSDK call), tried again when it times out, up to
        ``TRANSFER_ATTEMPTS`` times: whole-list uploads, downloads and clears, and starting the mission or setting
        its current item (a lost COMMAND_ACK or final MISSION_ACK is a timeout in MAVSDK; it never resends the
        last item, as with PX4). On the injected-faults run's lossy link a start_mission timed out as an upload
        had (``mission.client.retry``)."""
        return await retry_on_timeout(call, start, MissionRawError, MissionFailed)

    async def upload(self, items: list[MissionItem]) -> None:
        await self.retried("upload_mission", lambda: self._mr.upload_mission(items))
        self.items = list(items)

    async def download(self) -> list[MissionItem]:
        return list(await self.retried("download_mission", self._mr.download_mission))

    async def clear(self) -> None:
        await self.retried("clear_mission", self._mr.clear_mission)
        self.items = []

    async def start(self) -> None:
        await self.retried("start_mission", self._mr.start_mission)

    async def set_current(self, seq: int) -> None:
        await self.retried("set_current_mission_item", lambda: self._mr.set_current_mission_item(seq))

    async def progress(self) -> tuple[int, int]:
        p = await self._do("mission_progress", self._mr.mission_progress())
        return int(p.current), int(p.total)

    async def end_dwell(self) -> None:
        """Stop holding at the current dwell point and fly on to the next item."""
        current, total = await self.progress()
        if current + 1 < total:
            await self.set_current(current + 1)

    async def replace_remaining(self, points: list[DwellPoint], *, finish: str = "none") -> None:
        """Replace the rest of the mission with new dwell points; the vehicle flies them from the first."""
        if self._conn.home is None:
            raise MissionFailed("replace_remaining", "home unknown")
        await self.upload(build_items(points, self._conn.home, finish=finish))

    async def is_finished(self) -> bool:
        return bool(await self._do("is_mission_finished", self._mr.is_mission_finished()))

    async def wait_item(self, seq: int, timeout_s: float) -> None:
        """Wait until the current item is ``seq`` or later."""
        async def _wait():
            async for p in self._mr.subscribe_mission_progress():
                if p.current >= seq:
                    return
        try:
            await asyncio.wait_for(_wait(), timeout_s)
        except TimeoutError:
            raise MissionFailed("wait_item", f"item {seq} not reached in {timeout_s:g} s") from None

    async def wait_finished(self, timeout_s: float, poll_s: float = 0.1) -> None:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while not await self.is_finished():
            if loop.time() > deadline:
                raise MissionFailed("wait_finished", f"not finished after {timeout_s:g} s")
            await asyncio.sleep(poll_s)
