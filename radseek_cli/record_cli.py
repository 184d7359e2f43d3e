"""``radseek record``: write an MCAP log of the live zenoh topics and the vehicle's MAVLink (the log itself is
:mod:`radseek_io.mcap_log`)."""

from __future__ import annotations

from pathlib import Path

from radseek import topics
from radseek.coordinates import Home
from radseek.zenoh_auth import RECORDER
from radseek_cli.serve import serve_on_session
from radseek_io.dataset import read_scenario
from radseek_io.mcap_log import Recorder


def _one_chunk(name: str) -> bool:
    """A vehicle name usable in a key and a channel name (``topics.key``'s rule)."""
    try:
        topics.key(topics.POSE, name)
    except ValueError:
        return False
    return True


def main(argv: list[str] | None = None) -> int:
    """``radseek record``: write an MCAP log of the live zenoh topics and the vehicle's MAVLink."""
    import argparse

    from radseek.zenoh_session import add_arguments

    p = argparse.ArgumentParser(prog="radseek record", description=main.__doc__)
    p.add_argument("--out", type=Path, default=Path("runs/flight.mcap"),
                   help="MCAP file to write (default runs/flight.mcap)")
    p.add_argument("--mavlink-port", action="append", default=[], metavar="[VEHICLE=]PORT",
                   help="also record MAVLink arriving on this UDP port (e.g. the vehicle's --gcs-port), as "
                        "mavlink/<MESSAGE>; VEHICLE=PORT records it as mavlink/<VEHICLE>/<MESSAGE>; repeat for a team")
    p.add_argument("--scenario", type=Path,
                   help="scenario.json whose bounds and walls the log draws for Foxglove (foxglove/map)")
    p.add_argument("--home", default="47.397742,8.545594,488.0", metavar="LAT,LON,ALT",
                   help="home point (the vehicle's --home; default PX4 SITL's): places the estimated pose on the "
                        "map (foxglove/<vehicle>/location) of a vehicle whose MAVLink is not recorded")
    p.add_argument("--duration", type=float, help="wall seconds to record (default: until Ctrl-C / SIGTERM)")
    add_arguments(p)
    args = p.parse_args(argv)
    unnamed, named = None, {}
    for spec in args.mavlink_port:
        name, _, port = spec.rpartition("=")
        if not port.isdigit() or not 0 < int(port) < 65536 or (name and not _one_chunk(name)):
            p.error(f"--mavlink-port {spec!r}: expected PORT or VEHICLE=PORT (a UDP port 1-65535)")
        if name:
            named[name] = int(port)
        elif unnamed is None:
            unnamed = int(port)
        else:
            p.error("--mavlink-port: one unnamed port at most (name the others VEHICLE=PORT)")
    ports = ", ".join(str(v) for v in ([unnamed] if unnamed else []) + list(named.values()))
    if args.duration is not None and args.duration <= 0:
        p.error("--duration must be > 0")
    if args.out.exists() and args.out.is_dir():
        p.error(f"--out {args.out} is a directory")
    try:
        lat, lon, alt = (float(v) for v in args.home.split(","))
        home = Home(lat, lon, alt)
    except ValueError as exc:
        p.error(f"--home {args.home!r}: expected LAT,LON,ALT in degrees and metres ({exc})")
    scenario = None
    if args.scenario is not None:
        try:
            scenario = read_scenario(args.scenario)
        except (OSError, ValueError) as exc:
            p.error(f"--scenario: {exc}")  # the reader names the file and the key
    args.out.parent.mkdir(parents=True, exist_ok=True)
    return serve_on_session(
        "radseek record", args,
        lambda session: Recorder(args.out, session, mavlink_port=unnamed, mavlink_ports=named, scenario=scenario,
                                 home=home),
        OSError, lambda exc: f"UDP port(s) {ports} unavailable ({exc.strerror}): choose others with --mavlink-port",
        started=lambda rec: f"recording {topics.all_keys()} to {args.out}",
        stop=lambda rec: f"wrote {rec.stop()}: {rec.log.count} messages",  # the session is closed before this prints
        user=RECORDER)
