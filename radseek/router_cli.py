"""``radseek router``: a zenoh router on loopback (tcp/127.0.0.1:7447), multicast scouting off."""

from __future__ import annotations

import argparse
import signal
import threading

import zenoh

from radseek.zenoh_session import DEFAULT_ENDPOINT, router_config


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="radseek router", description=__doc__)
    p.add_argument("--listen", default=DEFAULT_ENDPOINT, help=f"endpoint to listen on (default {DEFAULT_ENDPOINT})")
    p.add_argument("--zenoh-config", metavar="FILE", help="standard zenoh JSON5 router config instead")
    args = p.parse_args(argv)
    conf = zenoh.Config.from_file(args.zenoh_config) if args.zenoh_config else router_config(args.listen)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with zenoh.open(conf) as session:
        print(f"radseek router {session.zid()} listening on {args.listen}", flush=True)
        try:
            stop.wait()
        except KeyboardInterrupt:
            pass
    return 0
