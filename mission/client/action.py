"""Vehicle actions through MAVSDK's Action plugin, in the stack's local ENU frame."""

from __future__ import annotations

import math

from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.plugins.action import ActionError

from mission.client.connection import Connection
from mission.client.retry import retry_on_timeout
from radseek.coordinates import enu_to_geodetic, yaw_enu_to_ned


class ActionFailed(Exception):
    """An action the vehicle refused or did not answer; ``result`` is MAVSDK's ActionResult name."""

    def __init__(self, call: str, result: str):
        super().__init__(f"{call}: {result}")
        self.call, self.result = call, result


class Actions:
    def __init__(self, conn: Connection):
        self._conn = conn
        self._action = ActionAsync(conn.system)

    async def _do(self, call: str, start) -> None:
        """Make the call (``start()`` makes the MAVSDK call), tried again when it times out, as mission transfers are
        (``mission.client.retry``): every action here is idempotent on the vehicle (arming an armed vehicle, a second
        takeoff, land, RTL or hold to the same target). A refusal is final."""
        await retry_on_timeout(call, start, ActionError, ActionFailed)

    async def arm(self) -> None:
        await self._do("arm", self._action.arm)

    async def disarm(self) -> None:
        await self._do("disarm", self._action.disarm)

    async def takeoff(self, altitude_m: float | None = None) -> None:
        if altitude_m is not None:
            await self._do("set_takeoff_altitude", lambda: self._action.set_takeoff_altitude(altitude_m))
        await self._do("takeoff", self._action.takeoff)

    async def land(self) -> None:
        await self._do("land", self._action.land)

    async def return_to_launch(self) -> None:
        await self._do("return_to_launch", self._action.return_to_launch)

    async def hold(self) -> None:
        await self._do("hold", self._action.hold)

    async def goto(self, x: float, y: float, z: float, yaw: float | None = None) -> None:
        """Fly to local ENU (x, y, z) m above home, facing ``yaw`` (rad CCW from east; None = keep)."""
        if self._conn.home is None:
            raise ActionFailed("goto", "home unknown: call connection.wait_healthy first")
        lat, lon, alt = enu_to_geodetic(self._conn.home, (x, y, z))
        yaw_deg = math.nan if yaw is None else math.degrees(yaw_enu_to_ned(yaw))
        await self._do("goto", lambda: self._action.goto_location(lat, lon, alt, yaw_deg))
