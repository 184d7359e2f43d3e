"""Move an unchanged MAVSDK-Python example off its fixed ports, as a second PX4 SITL instance moves its own:
with ``RADSEEK_EXAMPLE_MAVLINK_PORT`` and ``RADSEEK_EXAMPLE_GRPC_PORT`` set, MAVLink 14540 in every
``System.connect`` address (and in the default address) becomes the first, and mavsdk_server's gRPC port 50051
in ``System(...)`` the second. The script is not touched; two examples then run side by side without sharing a
port (tests/test_mavsdk_examples.py: no machine-wide lock)."""

import os

MAVLINK_ENV, GRPC_ENV = "RADSEEK_EXAMPLE_MAVLINK_PORT", "RADSEEK_EXAMPLE_GRPC_PORT"


def move_ports_from_env() -> None:
    """Point ``mavsdk.System`` at the ports the environment names (nothing when it names none)."""
    mav_port, grpc_port = os.environ.get(MAVLINK_ENV), os.environ.get(GRPC_ENV)
    if not (mav_port and grpc_port):
        return
    from mavsdk import System

    init, connect = System.__init__, System.connect

    def moved_init(self, mavsdk_server_address=None, port=50051, *args, **kwargs):
        init(self, mavsdk_server_address, int(grpc_port) if port == 50051 else port, *args, **kwargs)

    async def moved_connect(self, system_address=None):
        address = system_address or "udpin://0.0.0.0:14540"
        return await connect(self, address.replace(":14540", f":{mav_port}"))

    System.__init__, System.connect = moved_init, moved_connect
