"""A MAVSDK-Python client of the vehicle's MAVLink shell, run with the gRPC MAVSDK-Python 3.x of
``.venv-mavsdk-grpc`` (the API of the upstream ``shell.py`` example: ``drone.shell.send(command)``, ``receive()``).
It runs each command in turn, each to its prompt, prints the whole transcript, then one JSON line: the
version MAVSDK's info plugin read (AUTOPILOT_VERSION) and the value of ``--param`` by the parameter protocol.

Usage: python mavsdk_shell_client.py API_PORT GRPC_PORT --param NAME COMMAND...
"""

import argparse
import asyncio
import contextlib
import json

from mavsdk import System

PROMPT = "pxh> "


async def main(args) -> None:
    drone = System(port=args.grpc_port)
    await drone.connect(system_address=f"udpin://127.0.0.1:{args.api_port}")
    async for state in drone.core.connection_state():
        if state.is_connected:
            break
    got: list[str] = []

    async def collect():
        async for text in drone.shell.receive():
            got.append(text)

    async def prompts(n: int) -> None:
        while "".join(got).count(PROMPT) < n:
            await asyncio.sleep(0.05)

    task = asyncio.create_task(collect())
    # MAVSDK asks for replies (RESPOND) only once receive() is subscribed: the first newline goes again until
    # the shell's prompt comes back (the timeout paces the resends only)
    while PROMPT not in "".join(got):
        await drone.shell.send("\n")
        with contextlib.suppress(asyncio.TimeoutError):
            await asyncio.wait_for(prompts(1), 2.0)
    for command in args.commands:
        n = "".join(got).count(PROMPT) + 1
        await drone.shell.send(command)
        await prompts(n)
    version = await drone.info.get_version()
    value = await drone.param.get_param_float(args.param)
    task.cancel()
    print("".join(got))
    print(json.dumps({"flight_sw": [version.flight_sw_major, version.flight_sw_minor, version.flight_sw_patch],
                      args.param: value}))


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("api_port", type=int)
    parser.add_argument("grpc_port", type=int)
    parser.add_argument("--param", required=True)
    parser.add_argument("commands", nargs="+")
    asyncio.run(main(parser.parse_args()))
