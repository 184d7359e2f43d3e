"""The ``radseek`` console command: one subcommand per job, each owned by the package that does it.

Subcommand modules are imported lazily so that ``radseek echo`` does not pay for OMPL or MAVSDK.
Each module exposes ``main(argv: list[str] | None) -> int`` with its own argparse parser. A file a command cannot
read or write (an ``--out`` under a file, a full disk) ends it with one line naming the file, exit 1, whichever
command it is: ``radseek compare: /x/f/cmp.png: Not a directory (ENOTDIR)``.
"""

from __future__ import annotations

import importlib
import sys

# name -> (module, one-line description)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "run": ("radseek_cli.run_cli", "fly a search mission against the mock vehicle and write a report"),
    "router": ("radseek_cli.router_cli", "run the zenoh router on tcp/127.0.0.1:7447 (loopback only)"),
    "detector": ("radseek_cli.detector_cli", "run the emulated 32-channel spectroscopy board"),
    "vehicle": ("radseek_cli.vehicle_cli", "run the mock autopilot (MAVLink 2 over UDP, SITL ports)"),
    "mission": ("radseek_cli.mission_cli", "run the mission process (dwell control, estimator, planner)"),
    "zenoh-credentials": ("radseek_cli.zenoh_credentials_cli", "write the zenoh users of the docker compose stack"),
    "topics": ("radseek_cli.inspect_cli", "list live radseek zenoh keys with their rates"),
    "echo": ("radseek_cli.echo_cli", "print messages on a zenoh key readably"),
    "record": ("radseek_cli.record_cli", "write an MCAP log of the zenoh topics and MAVLink (Foxglove, mcap reader)"),
    "view": ("radseek_cli.live_view", "live view of a flight in Foxglove (map, path, estimate, spectra; opt-in)"),
    "simulate-dataset": ("radseek_cli.simulate_cli", "write a simulated flight in the dataset format"),
    "localize": ("radseek_cli.localize_cli", "estimate source position and strength from a dataset"),
    "compare": ("radseek_cli.compare_cli", "compare two flights' particle-filter runs (paper 000 metrics)"),
    "diagnose": ("radseek_cli.diagnose_cli", "compare model and measurements, find the missing effect"),
    "replay": ("radseek_cli.replay_cli", "re-run the estimator on a recorded flight"),
    "plan": ("radseek_cli.plan_cli", "plan the next dwell points for a scene and print/plot them"),
    "calibrate": ("radseek_cli.calibrate_cli", "fit the detector response to a measured spectrum; name what it misses"),
    "spectra": ("radseek_cli.flight_cli", "show spectrum files; export dwell spectra as N42; import flights"),
    "campaign": ("radseek_cli.campaign_cli", "fly many seeded searches as Ray tasks (local or a cluster) into Parquet"),
}


def _usage() -> str:
    width = max(map(len, SUBCOMMANDS))
    lines = ["usage: radseek COMMAND [options]   (radseek COMMAND --help for details)", "", "commands:"]
    lines += [f"  {name:<{width}}  {desc}" for name, (_, desc) in SUBCOMMANDS.items()]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in {"-h", "--help", "help"}:
        print(_usage())
        return 0
    if argv[0] == "--version":
        from radseek import __version__

        print(f"radseek {__version__}")
        return 0
    name, rest = argv[0], argv[1:]
    if name not in SUBCOMMANDS:
        print(f"radseek: unknown command {name!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    module_name = SUBCOMMANDS[name][0]
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name == module_name:
            print(f"radseek: command {name!r} is not available in this build", file=sys.stderr)
            return 2
        raise
    try:
        return int(module.main(rest) or 0)
    except KeyboardInterrupt:
        return 130
    except OSError as exc:
        if not exc.filename:  # not a file's: a bug or a socket, with its traceback
            raise
        from radseek_io.outdir import file_problem

        print(f"radseek {name}: {file_problem(exc)}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
