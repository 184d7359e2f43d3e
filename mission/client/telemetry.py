"""Telemetry through MAVSDK's Telemetry plugin, converted to the stack's local ENU frame."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import numpy as np
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

from mission.client.connection import Connection
from radseek.coordinates import geodetic_to_enu


class TelemetryTimeout(Exception):
    """A condition on the telemetry did not come true in time."""


class TelemetryWatch:
    def __init__(self, conn: Connection):
        self._conn = conn
        self._tel = TelemetryAsync(conn.system)

    async def position_enu(self) -> np.ndarray:
        """Next reported position, local ENU m about home."""
        async for p in self._tel.subscribe_position():
            if p.latitude_deg == p.latitude_deg:
                return geodetic_to_enu(self._conn.home, p.latitude_deg, p.longitude_deg, p.absolute_altitude_m)
        raise TelemetryTimeout("position stream ended")

    async def wait_position(self, pred: Callable[[np.ndarray], bool], timeout_s: float) -> np.ndarray:
        async def _wait():
            async for p in self._tel.subscribe_position():
                if p.latitude_deg != p.latitude_deg:
                    continue
                pos = geodetic_to_enu(self._conn.home, p.latitude_deg, p.longitude_deg, p.absolute_altitude_m)
                if pred(pos):
                    return pos
        try:
            return await asyncio.wait_for(_wait(), timeout_s)
        except TimeoutError:
            raise TelemetryTimeout(f"position condition not met in {timeout_s:g} s") from None

    async def wait_in_air(self, in_air: bool, timeout_s: float) -> None:
        async def _wait():
            async for v in self._tel.subscribe_in_air():
                if v == in_air:
                    return
        try:
            await asyncio.wait_for(_wait(), timeout_s)
        except TimeoutError:
            raise TelemetryTimeout(f"in_air != {in_air} after {timeout_s:g} s") from None

    async def in_air(self) -> bool:
        async for v in self._tel.subscribe_in_air():
            return bool(v)
        return False

    async def armed(self) -> bool:
        async for v in self._tel.subscribe_armed():
            return bool(v)
        return False

    async def battery_remaining(self) -> float:
        """Remaining fraction in [0, 1]."""
        async for b in self._tel.subscribe_battery():
            return float(b.remaining_percent) / (100.0 if b.remaining_percent > 1.0 else 1.0)
        return float("nan")

    async def flight_mode(self) -> str:
        async for m in self._tel.subscribe_flight_mode():
            return m.name
        return "UNKNOWN"

    async def status_texts(self):
        """Async iterator of (type name, text)."""
        async for s in self._tel.subscribe_status_text():
            yield s.type.name, s.text

    async def battery_levels(self):
        """Async iterator of the remaining fraction in [0, 1], as reported."""
        async for b in self._tel.subscribe_battery():
            yield float(b.remaining_percent) / (100.0 if b.remaining_percent > 1.0 else 1.0)

    async def in_air_states(self):
        """Async iterator of the in-air flag, as reported."""
        async for v in self._tel.subscribe_in_air():
            yield bool(v)
