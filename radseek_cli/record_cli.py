"""``radseek record``: write an MCAP log of the live zenoh topics and the vehicle's MAVLink (the log itself is
:mod:`radseek_io.mcap_log`)."""

from __future__ import annotations

from pathlib import Path

from radseek import topics
from radseek_cli.serve import serve_on_session
from radseek_io.mcap_log import Recorder


def main(argv: list[str] | None = None) -> int:
    """``radseek record``: write an MCAP log of the live zenoh topics and the vehicle's MAVLink."""
    import argparse

    from radseek.zenoh_session import add_arguments

    p = argparse.ArgumentParser(prog="radseek record", description=main.__doc__)
    p.add_argument("--out", type=Path, default=Path("runs/flight.mcap"),
                   help="MCAP file to write (default runs/flight.mcap)")
    p.add_argument("--mavlink-port", type=int, default=None,
                   help="also record MAVLink arriving on this UDP port (e.g. the vehicle's --gcs-port)")
    p.add_argument("--duration", type=float, help="wall seconds to record (default: until Ctrl-C / SIGTERM)")
    add_arguments(p)
    args = p.parse_args(argv)
    if args.duration is not None and args.duration <= 0:
        p.error("--duration must be > 0")
    if args.out.exists() and args.out.is_dir():
        p.error(f"--out {args.out} is a directory")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    return serve_on_session(
        "radseek record", args, lambda session: Recorder(args.out, session, mavlink_port=args.mavlink_port),
        OSError, lambda exc: f"UDP port {args.mavlink_port} unavailable ({exc.strerror}): choose another with "
                             "--mavlink-port",
        started=lambda rec: f"recording {topics.all_keys()} to {args.out}",
        stop=lambda rec: f"wrote {rec.stop()}: {rec.log.count} messages")  # the session is closed before this prints
