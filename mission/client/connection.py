"""Connect to a vehicle with MAVSDK and wait until it is healthy enough to fly."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass
from enum import Enum

from mavsdk.asyncio import Configuration, Mavsdk
from mavsdk.asyncio.exceptions import MavsdkConnectionError
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.component_type import ComponentType

from radseek.coordinates import Home

DEFAULT_URL = "udpin://0.0.0.0:14540"  # PX4 SITL's API port: the vehicle sends there


class ConnectionResult(Enum):
    SUCCESS = "success"
    NO_VEHICLE = "no autopilot heartbeat"
    NO_LINK = "cannot open the MAVLink link"
    NOT_HEALTHY = "vehicle not healthy (no position or home)"


class ConnectionFailed(Exception):
    def __init__(self, result: ConnectionResult, detail: str = ""):
        super().__init__(f"{result.value}{': ' + detail if detail else ''}")
        self.result = result


@dataclass
class Connection:
    """An open MAVSDK instance with one autopilot system and its home point."""

    sdk: Mavsdk
    system: object  # mavsdk.asyncio.System
    home: Home | None = None

    async def close(self) -> None:
        self.sdk.destroy()


async def connect(url: str = DEFAULT_URL, timeout_s: float = 30.0) -> Connection:
    """Open ``url`` (e.g. ``udpin://0.0.0.0:14540``) and return the first autopilot found."""
    sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        await sdk.add_any_connection(url)
    except MavsdkConnectionError as exc:  # e.g. BIND_ERROR: the port is taken
        sdk.destroy()
        raise ConnectionFailed(ConnectionResult.NO_LINK, f"{url}: {exc} (is another radseek run, SITL or ground "
                                                          "station listening on that port? radseek run "
                                                          "--mavlink-port chooses another)") from None
    system = await sdk.first_autopilot(timeout_s)
    if system is None:
        sdk.destroy()
        raise ConnectionFailed(ConnectionResult.NO_VEHICLE, f"{url} after {timeout_s:g} s")
    return Connection(sdk, system)


async def wait_healthy(conn: Connection, timeout_s: float = 30.0) -> Home:
    """Wait for local/global position and home to be OK; stores and returns the home point."""
    tel = TelemetryAsync(conn.system)

    async def _wait() -> Home:
        async for h in tel.subscribe_health():
            if h.is_global_position_ok and h.is_home_position_ok and h.is_local_position_ok:
                break
        async for hp in tel.subscribe_home():
            if hp.latitude_deg == hp.latitude_deg:  # not NaN
                return Home(hp.latitude_deg, hp.longitude_deg, hp.absolute_altitude_m)
        raise ConnectionFailed(ConnectionResult.NOT_HEALTHY)

    try:
        conn.home = await asyncio.wait_for(_wait(), timeout_s)
    except TimeoutError:
        raise ConnectionFailed(ConnectionResult.NOT_HEALTHY, f"after {timeout_s:g} s") from None
    return conn.home
