"""The autopilot as the mission executive commands it (``mission.executive.VehicleLink``), over MAVSDK.

Actions (arm, takeoff, return, land) through ``mission.client.action``, the dwell points through
``mission.client.mission_upload``; ``watch()`` follows the battery, the STATUSTEXTs and the in-air flag, and
sets ``abort_reason`` when the vehicle leaves the search (a failsafe, a landing nobody asked for).
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable

from mission.client.action import Actions
from mission.client.connection import Connection
from mission.client.mission_upload import DwellPoint, MissionControl
from mission.client.telemetry import TelemetryWatch


class MavsdkVehicle:
    def __init__(self, conn: Connection, on_text: Callable[[str, str], None] | None = None):
        self.actions, self.mission, self.tel = Actions(conn), MissionControl(conn), TelemetryWatch(conn)
        self._on_text = on_text
        self.abort_reason: str | None = None
        self.battery = math.nan
        self.airborne = False

    async def watch(self) -> None:
        """Background: keep the battery level and log every STATUSTEXT (failsafes say why here)."""

        async def battery() -> None:
            async for level in self.tel.battery_levels():
                self.battery = level

        async def texts() -> None:
            async for severity, text in self.tel.status_texts():
                if self._on_text is not None:
                    self._on_text(severity, text)
                if text.lower().startswith("failsafe") and self.abort_reason is None:
                    self.abort_reason = f"vehicle failsafe: {text}"

        async def in_air() -> None:
            async for flying in self.tel.in_air_states():
                if self.airborne and not flying and self.abort_reason is None:
                    self.abort_reason = "vehicle landed"
                self.airborne = self.airborne or flying

        await asyncio.gather(battery(), texts(), in_air())

    async def arm(self) -> None:
        await self.actions.arm()

    async def takeoff(self, altitude_m: float) -> None:
        await self.actions.takeoff(altitude_m)

    async def fly(self, points: list[DwellPoint]) -> None:
        await self.mission.replace_remaining(points)
        await self.mission.start()  # (re)enter AUTO.MISSION at the new first item

    async def end_dwell(self) -> None:
        await self.mission.end_dwell()

    async def return_to_launch(self) -> None:
        await self.actions.return_to_launch()

    async def land(self) -> None:
        await self.actions.land()

    async def in_air(self) -> bool:
        return await self.tel.in_air()
