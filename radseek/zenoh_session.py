"""The one place the zenoh configuration is built: every radseek process opens its session here.

Default wiring is like ``zenohd``'s: ``radseek router`` listens on ``tcp/127.0.0.1:7447`` (zenoh's
default port, loopback only, multicast scouting off); every other process is a peer that connects
there as a zenoh *client* and listens nowhere. ``--zenoh-config FILE`` replaces all of that with a
standard zenoh JSON5 configuration for other networks.

Why client and not peer: with zenoh 1.10, two peers that both connect only to the router and listen
nowhere exchange nothing (peer gossip tells them to connect to each other directly, which they
cannot). Clients route everything through the router, which is the wiring we want.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import zenoh

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def router_config(endpoint: str = DEFAULT_ENDPOINT) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("router"))
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


def client_config(config_file: str | Path | None = None, connect: str = DEFAULT_ENDPOINT) -> zenoh.Config:
    """Client config connecting to the router at ``connect``, or the user's own JSON5 file."""
    if config_file is not None:
        path = Path(config_file)
        if not path.is_file():
            raise FileNotFoundError(f"zenoh config file {path} does not exist")
        return zenoh.Config.from_file(str(path))
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("client"))
    conf.insert_json5("connect/endpoints", json.dumps([connect]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The zenoh options every radseek process takes."""
    g = parser.add_argument_group("zenoh")
    g.add_argument("--zenoh-config", metavar="FILE", help="standard zenoh JSON5 config (overrides --connect)")
    g.add_argument("--connect", default=DEFAULT_ENDPOINT, help=f"router endpoint (default {DEFAULT_ENDPOINT})")
    g.add_argument("--vehicle-name", default="uav0", help="vehicle key chunk: radseek/<name>/... (default uav0)")


def open_session(
    config_file: str | Path | None = None,
    connect: str = DEFAULT_ENDPOINT,
    *,
    wait_for_router_s: float = 30.0,
) -> zenoh.Session:
    """Open a client session, retrying until the router answers (or ``wait_for_router_s`` passes).

    Raises ``TimeoutError`` naming the endpoint, with the command that starts a router.
    """
    if config_file is not None:
        return zenoh.open(client_config(config_file, connect))
    deadline = time.monotonic() + wait_for_router_s
    while True:
        try:
            return zenoh.open(client_config(config_file, connect))
        except zenoh.ZError as exc:
            if time.monotonic() > deadline:
                reason = str(exc).split(" at /")[0]  # zenoh appends its Rust source location
                raise TimeoutError(
                    f"no zenoh router at {connect} after {wait_for_router_s:.0f} s ({reason}): "
                    "start one with 'radseek router'"
                ) from None
            time.sleep(0.2)


def session_from_args(args: argparse.Namespace, *, wait_for_router_s: float = 30.0) -> zenoh.Session:
    return open_session(args.zenoh_config, args.connect, wait_for_router_s=wait_for_router_s)
