"""``radseek router``: a zenoh router on loopback (tcp/127.0.0.1:7447), multicast scouting off.

With RADSEEK_ZENOH_CREDENTIALS=FILE in its environment it admits only the users FILE lists (USER:PASSWORD
lines) and lets each put only its own keys: ROLE@VEHICLE puts that role's keys of that vehicle (detector,
vehicle, mission), any other name only reads (radseek/zenoh_auth.py, docs/topics.md "Authentication").
"""

from __future__ import annotations

import argparse
import socket
import sys

import zenoh

from radseek.zenoh_auth import CredentialsError, credentials_file, read_credentials
from radseek.zenoh_session import DEFAULT_ENDPOINT, router_config, tcp_address
from radseek_cli.serve import StopSignals


def _in_use(endpoint: str) -> bool:
    """True if a tcp/HOST:PORT endpoint cannot be bound because something holds it."""
    address = tcp_address(endpoint)
    if address is None:
        return False
    try:
        with socket.socket() as s:
            s.bind(address)
        return False
    except OSError:
        return True


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="radseek router", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--listen", default=DEFAULT_ENDPOINT, help=f"endpoint to listen on (default {DEFAULT_ENDPOINT})")
    p.add_argument("--zenoh-config", metavar="FILE", help="standard zenoh JSON5 router config instead")
    args = p.parse_args(argv)
    credentials = credentials_file()
    try:
        conf = zenoh.Config.from_file(args.zenoh_config) if args.zenoh_config else \
            router_config(args.listen, credentials)
        users = read_credentials(credentials) if credentials and not args.zenoh_config else None
    except CredentialsError as exc:
        print(f"radseek router: {exc}", file=sys.stderr)
        return 2
    zenoh.init_log_from_env_or("error")  # zenoh's own errors (a transport it closes) in the router's log
    with StopSignals() as stop:  # a SIGTERM from the moment the router starts stops it
        try:
            session = zenoh.open(conf)
        except zenoh.ZError as exc:
            if args.zenoh_config is None and _in_use(args.listen):
                print(f"radseek router: {args.listen} is already in use (another router?): stop it, or listen "
                      "elsewhere with --listen tcp/127.0.0.1:PORT and give the others --connect tcp/127.0.0.1:PORT",
                      file=sys.stderr)
            else:
                print(f"radseek router: cannot listen on {args.listen}: {exc}", file=sys.stderr)
            return 1
        with session:
            auth = "open to any session" if users is None else \
                f"admitting {len(users)} users of {credentials} (each puts only its own keys)"
            print(f"radseek router {session.zid()} listening on {args.listen}, {auth}", flush=True)
            stop.wait()
    return 0
