"""Interoperability: MAVSDK's Action and Telemetry plugins (through radseek's client) against the vehicle
process: takeoff to a set altitude (MAVSDK sets MIS_TAKEOFF_ALT by parameter), go-to with yaw, hold,
return to launch; flight modes and status texts as MAVSDK decodes them."""

import asyncio
import math

import numpy as np
import pytest

from mission.client import action, connection, telemetry
from vehicle_sim.harness import VehicleProcess, free_udp_port

pytestmark = pytest.mark.slow


async def session(api_port: int) -> dict:
    conn = await connection.connect(f"udpin://127.0.0.1:{api_port}", timeout_s=60)
    out: dict = {"modes": []}
    try:
        await connection.wait_healthy(conn, timeout_s=60)
        tel, act = telemetry.TelemetryWatch(conn), action.Actions(conn)
        with pytest.raises(action.ActionFailed):
            await act.takeoff()  # disarmed: refused, and MAVSDK reports it
        texts: list[str] = []

        async def collect():
            async for _, text in tel.status_texts():
                texts.append(text)

        collector = asyncio.create_task(collect())
        await act.arm()
        out["armed"] = await tel.armed()
        await act.takeoff(altitude_m=4.0)
        await tel.wait_position(lambda p: abs(p[2] - 4.0) < 0.1, timeout_s=60)
        out["modes"].append(await tel.flight_mode())
        await act.goto(6.0, -3.0, 5.0, yaw=math.pi)  # ENU: face west
        out["goto"] = await tel.wait_position(lambda p: np.linalg.norm(p - [6, -3, 5]) < 0.2, timeout_s=60)
        await act.hold()
        out["modes"].append(await tel.flight_mode())
        await act.return_to_launch()
        out["modes"].append(await tel.flight_mode())
        await tel.wait_in_air(False, timeout_s=60)
        out["landed_at"] = await tel.position_enu()
        await asyncio.sleep(0.3)
        collector.cancel()
        out["texts"] = texts
    finally:
        await conn.close()
    return out


def test_mavsdk_actions_and_modes():
    api = free_udp_port()
    with VehicleProcess(api, free_udp_port(), ["--speedup", "20"]):
        out = asyncio.run(asyncio.wait_for(session(api), 400))  # bounds waiting only
    assert out["armed"]
    assert out["modes"] == ["HOLD", "HOLD", "RETURN_TO_LAUNCH"]
    assert np.linalg.norm(out["goto"] - [6, -3, 5]) < 0.2
    assert np.linalg.norm(out["landed_at"][:2]) < 0.3 and abs(out["landed_at"][2]) < 0.1
    assert "Takeoff complete" in out["texts"] and "Landing detected" in out["texts"]
