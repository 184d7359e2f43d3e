"""``radseek mission``: the mission process (dwell control, estimator, planner, MAVSDK client, recorder).

It reads only the operator's scenario (``scenario.json`` of the dataset format: walls, bounds,
background estimate) and flies a search against whatever autopilot answers on ``--url``; the recorded
flight is written to ``--out`` as a dataset, with ``mission_summary.json`` and ``mission_log.jsonl``.
A non-empty ``--out`` is refused unless ``--force`` (which removes the previous mission outputs there
first, the summary before the data; other files are kept); ``mission_summary.json`` is written
atomically when the vehicle has landed, frames as they arrive.

exit codes (as ``radseek run``'s):
  0  the search ended on its own criterion with the source located (or a pattern flown to its end)
  1  the flight failed: no vehicle, a refused command, a mission error (with --plan: the plan failed)
  2  usage: bad options or scenario, or --out is not empty and --force was not given
  3  the search failed: aborted (failsafe, vehicle landed, ...) or ended without locating the source;
     the recorded flight and mission_summary.json are kept for examination
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from mission.client.connection import DEFAULT_URL
from mission.search import STRATEGIES, search_failure
from radseek import topics, zenoh_session
from radseek.dataset import DatasetError
from radseek_io.dataset import read_scenario
from radseek_io.outdir import OutputDirError, file_problem, prepare_output

#: what a mission writes under --out, summaries first: --force removes them in this order
MISSION_OUTPUTS = ("mission_summary.json", "truth.json", "frames.csv", "frames_flagged.csv", "mission_log.jsonl",
                   "scenario.json")


def _write_error(exc: OSError) -> str:
    """One line for a failed write: the file, the system's words and the errno's name."""
    from radseek_io.dataset import FrameWriteError

    if isinstance(exc, FrameWriteError) or not exc.filename:
        return str(exc)
    return f"cannot write {file_problem(exc)}"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="radseek mission", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenario", help="scenario.json (the operator's view of the scene); required unless --plan")
    p.add_argument("--out", help="directory for the recorded dataset and mission summary "
                   "(must be empty unless --force); required unless --plan")
    p.add_argument("--force", action="store_true",
                   help="use a non-empty --out: remove its previous mission outputs first (other files are kept)")
    p.add_argument("--url", default=DEFAULT_URL, help="MAVSDK connection URL (default PX4 SITL's)")
    p.add_argument("--seed", type=int, default=0, help="seed of the planner's random tree")
    p.add_argument("--speedup", type=float, default=None,
                   help="the run's sim seconds per wall second: sets each key's expected rate, over which a "
                        "publisher's samples are dropped as a flood (default: follow the vehicle's clock, as "
                        "measured from its poses)")
    p.add_argument("--connect-timeout", type=float, default=60.0, metavar="S",
                   help="wall seconds to wait for the zenoh router and for the autopilot's heartbeat and health "
                        "(default 60; a booting SITL may need more)")
    p.add_argument("--altitude", type=float, default=1.5, help="dwell altitude, m (default 1.5)")
    p.add_argument("--stop-sigma", type=float, default=0.10, help="stop when the 1-sigma error ellipse is below, m")
    p.add_argument("--max-dwells", type=int, default=16, help="dwell budget in all (default 16)")
    p.add_argument("--localizer", default="mle", help="estimator used in flight (default mle)")
    p.add_argument("--strategy", default="active", choices=STRATEGIES,
                   help="active search: next dwell by paper 003's eq. 6 (active) or by the information planner (info: "
                        "D-optimal under drift, dwell length by information per second); or a fixed pattern baseline "
                        "(default active)")
    p.add_argument("--plan", type=Path, metavar="FILE",
                   help="instead of a search: fly a QGroundControl .plan file (mission, geofence, rally points)")
    p.add_argument("--team", metavar="NAMES",
                   help="fly as one vehicle of a team (radseek run --vehicles N): the team's vehicle names, "
                        "comma-separated, this one (--vehicle-name) included; one joint estimate and allocation")
    zenoh_session.add_arguments(p)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="radseek mission: %(message)s", stream=sys.stderr)
    if args.plan is not None:
        from mission.client.connection import ConnectionFailed
        from mission.client.mission_upload import MissionFailed
        from mission.plan_flight import run

        if not args.plan.is_file():
            p.error(f"--plan {args.plan}: no such file")
        try:
            print(json.dumps(run(args.plan, args.url)))
        except (ConnectionFailed, MissionFailed) as exc:
            print(f"radseek mission: {exc}", file=sys.stderr)
            return 1
        return 0
    if args.scenario is None or args.out is None:
        p.error("--scenario and --out are required (or --plan FILE)")

    from mission.mission_process import MissionSettings, run_mission
    from mission.search import SearchConfig

    try:
        scenario = read_scenario(Path(args.scenario))
    except DatasetError as exc:
        print(f"radseek mission: {exc}", file=sys.stderr)
        return 2
    try:
        prepare_output(args.out, force=args.force, outputs=MISSION_OUTPUTS)
    except OutputDirError as exc:
        print(f"radseek mission: {exc}", file=sys.stderr)
        return 2
    config = SearchConfig(altitude_m=args.altitude, stop_sigma_m=args.stop_sigma,
                          max_dwells=args.max_dwells, max_search_dwells=min(6, args.max_dwells),
                          localizer=args.localizer, strategy=args.strategy)
    if args.speedup is not None and not 0 < args.speedup <= topics.SPEEDUP_MAX:
        p.error(f"--speedup must be in (0, {topics.SPEEDUP_MAX:g}], got {args.speedup}")
    if not args.connect_timeout > 0:
        p.error(f"--connect-timeout must be > 0 s, got {args.connect_timeout}")
    team = tuple(n.strip() for n in args.team.split(",")) if args.team else ()
    if team:
        from mission.team import MAX_VEHICLES

        if args.vehicle_name not in team or len(set(team)) != len(team) or not 2 <= len(team) <= MAX_VEHICLES:
            p.error(f"--team {args.team!r}: 2..{MAX_VEHICLES} distinct names including --vehicle-name "
                    f"{args.vehicle_name!r}")
        if args.strategy != "active":
            p.error("--team flies the active search only")
    settings = MissionSettings(url=args.url, vehicle=args.vehicle_name, seed=args.seed,
                               connect_timeout_s=args.connect_timeout, team=team, speedup=args.speedup)
    from mission.client.connection import ConnectionFailed
    from mission.executive import FlightStopped

    try:
        # --connect-timeout governs every wait: the router's as well as the autopilot's
        session = zenoh_session.session_from_args(args, "mission", wait_for_router_s=args.connect_timeout)
    except zenoh_session.OPEN_ERRORS as exc:
        print(f"radseek mission: {exc}", file=sys.stderr)
        return 1
    try:
        with session:
            summary = run_mission(session, scenario, Path(args.out), config, settings)
    except ConnectionFailed as exc:
        print(f"radseek mission: {exc} (frames recorded while waiting are in {args.out})", file=sys.stderr)
        return 1
    except FlightStopped as exc:  # no detector, no pose, no takeoff: the stack is broken, said in one line
        print(f"radseek mission: {exc} (the frames recorded so far are in {args.out})", file=sys.stderr)
        return 1
    except OSError as exc:  # a write to the dataset failed (disk full, file too large): the cause, named
        print(f"radseek mission: {_write_error(exc)}", file=sys.stderr)
        return 1
    print(json.dumps({k: summary[k] for k in ("reason", "dwell_points", "mission_time_s", "estimate")},
                     default=float))
    failure = search_failure(summary)
    if failure is not None:
        print(f"radseek mission: search failed: {failure}", file=sys.stderr)
        return 3
    return 0
