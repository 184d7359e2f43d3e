"""The one place the zenoh configuration is built: every radseek process opens its session here.

Default wiring is like ``zenohd``'s: ``radseek router`` listens on ``tcp/127.0.0.1:7447`` (zenoh's
default port, loopback only, multicast scouting off); every other process is a peer that connects
there as a zenoh *client* and listens nowhere. ``--zenoh-config FILE`` replaces all of that with a
standard zenoh JSON5 configuration for other networks.

Why client and not peer: with zenoh 1.10, two peers that both connect only to the router and listen
nowhere exchange nothing (peer gossip tells them to connect to each other directly, which they
cannot). Clients route everything through the router, which is the wiring we want.

Authentication: when the environment variable ``RADSEEK_ZENOH_CREDENTIALS`` names a credentials file
(``radseek.zenoh_auth``; ``radseek run`` sets it for its processes), the router admits only the users it lists
and lets each put only its own keys, and every process connects as its own user from it.
"""

from __future__ import annotations

import argparse
import json
import socket
import time
from pathlib import Path

import zenoh

from radseek import zenoh_auth, zenoh_qos
from radseek.zenoh_auth import CredentialsError, User

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


class RouterRefused(ConnectionError):
    """A router answers on the endpoint but refuses the session (credentials)."""


#: what ``open_session`` raises instead of opening a session (each message is one line)
OPEN_ERRORS = (TimeoutError, FileNotFoundError, CredentialsError, RouterRefused)


def router_config(endpoint: str = DEFAULT_ENDPOINT, credentials: str | Path | None = None) -> zenoh.Config:
    """The router's config: the stack's QoS policy (``radseek.zenoh_qos``); with a ``credentials`` file, it
    admits only its users and applies their ACL."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("router"))
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("qos/network", json.dumps(zenoh_qos.network_qos()))
    if credentials is not None:
        users = zenoh_auth.read_credentials(credentials)
        conf.insert_json5("transport/auth/usrpwd", json.dumps({"dictionary_file": str(Path(credentials).resolve())}))
        conf.insert_json5("access_control", json.dumps(zenoh_auth.access_control(users)))
    return conf


def client_config(config_file: str | Path | None = None, connect: str = DEFAULT_ENDPOINT,
                  user: User | None = None) -> zenoh.Config:
    """Client config connecting to the router at ``connect`` (as ``user``), or the user's own JSON5 file."""
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
    if user is not None:
        conf.insert_json5("transport/auth/usrpwd", json.dumps({"user": user.name, "password": user.password}))
    return conf


def tcp_address(endpoint: str) -> tuple[str, int] | None:
    """(host, port) of a ``tcp/HOST:PORT`` endpoint; None for another protocol or a malformed endpoint."""
    try:
        proto, addr = endpoint.split("/", 1)
        host, port = addr.rsplit(":", 1)
        return (host.strip("[]"), int(port)) if proto == "tcp" else None
    except ValueError:
        return None


def _answers(endpoint: str) -> bool:
    """True if something accepts a TCP connection on a tcp/HOST:PORT endpoint."""
    address = tcp_address(endpoint)
    if address is None:
        return False
    try:
        with socket.create_connection(address, timeout=1.0):
            return True
    except OSError:
        return False


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The zenoh options every radseek process takes."""
    g = parser.add_argument_group("zenoh")
    g.add_argument("--zenoh-config", metavar="FILE", help="standard zenoh JSON5 config (overrides --connect)")
    g.add_argument("--connect", default=DEFAULT_ENDPOINT, help=f"router endpoint (default {DEFAULT_ENDPOINT})")
    g.add_argument("--vehicle-name", default="uav0", help="vehicle key chunk: radseek/<name>/... (default uav0)")


def session_user(role: str | None = None, vehicle: str | None = None, *, prefer: str | None = None,
                 credentials: str | Path | None = None) -> User | None:
    """The user a process of ``role`` (None: a reader) on ``vehicle`` connects as: its line of ``credentials``
    (default: the file ``RADSEEK_ZENOH_CREDENTIALS`` names), or None on an open network."""
    path = credentials if credentials is not None else zenoh_auth.credentials_file()
    if path is None:
        return None
    return zenoh_auth.find_user(zenoh_auth.read_credentials(path), role, vehicle, prefer=prefer, source=path)


def open_session(
    config_file: str | Path | None = None,
    connect: str = DEFAULT_ENDPOINT,
    *,
    user: User | None = None,
    wait_for_router_s: float = 30.0,
) -> zenoh.Session:
    """Open a client session (as ``user``: see :func:`session_user`; or as a ``config_file`` says), retrying until
    the router answers (or ``wait_for_router_s`` passes).

    Raises ``TimeoutError`` naming the endpoint, with the command that starts a router, and ``RouterRefused``
    naming the user and the endpoint when a router answers there but does not admit the session.
    """
    conf = client_config(config_file, connect, user)
    if config_file is not None:  # the file's own endpoint and user are the ones named
        endpoints = _json(conf, "connect/endpoints") or []
        connect = next((e for e in endpoints if isinstance(e, str)), None)
        if connect is None:  # no router to wait for (a peer scouting its network): zenoh says what is wrong
            return zenoh.open(conf)
        name = _json(conf, "transport/auth/usrpwd/user")
        user = User(name, "") if isinstance(name, str) else None
    deadline = time.monotonic() + wait_for_router_s
    refused = 0
    while True:
        try:
            return zenoh.open(conf)
        except zenoh.ZError as exc:
            refused = refused + 1 if _answers(connect) else 0
            if refused >= 3:  # a router that is up says no, again and again (not a slow start)
                raise RouterRefused(_refusal(connect, user, config_file)) from None
            if time.monotonic() > deadline:
                reason = str(exc).split(" at /")[0]  # zenoh appends its Rust source location
                raise TimeoutError(
                    f"no zenoh router at {connect} after {wait_for_router_s:.0f} s ({reason}): "
                    "start one with 'radseek router'"
                ) from None
            time.sleep(0.2)


def _json(conf: zenoh.Config, key: str):
    """A value of a zenoh config, None where it has none."""
    try:
        return json.loads(conf.get_json(key))
    except (zenoh.ZError, ValueError):
        return None


def _refusal(connect: str, user: User | None, config_file: str | Path | None) -> str:
    """One line: the router at ``connect`` refused ``user`` (and what to check)."""
    source = f" of {config_file}" if config_file is not None else ""
    if user is not None:
        who = f"user {user.name!r}{source} (wrong password, or that router has other credentials)"
    elif config_file is not None:
        who = f"a session without credentials ({config_file} gives no transport.auth.usrpwd user)"
    else:
        who = f"a session without credentials (give them with {zenoh_auth.CREDENTIALS_ENV}=FILE)"
    return f"the zenoh router at {connect} refused {who}"


def session_from_args(args: argparse.Namespace, role: str | None = None, *, prefer: str | None = None,
                      wait_for_router_s: float = 30.0) -> zenoh.Session:
    """The session a process of ``role`` (None: a reader) asks for with its :func:`add_arguments` options."""
    user = None if args.zenoh_config else session_user(role, args.vehicle_name, prefer=prefer)
    return open_session(args.zenoh_config, args.connect, user=user, wait_for_router_s=wait_for_router_s)
