"""``radseek run [SCENE]``: fly a whole search against the mock vehicle and write a report.

Starts the stack as separate processes on loopback — the zenoh router, the mock autopilot (owner of
the simulation clock and the true pose), the detector emulator (following that clock, reading the
true pose) and the mission process (MAVSDK client, dwell controller, estimator, planner, recorder) —
shows live progress, stops when the mission lands, then writes under ``--out``: ``dataset/`` (the
recorded flight in the dataset format, plus ``truth.json``), ``flight.mcap``, ``report.png``,
``summary.json`` and the processes' logs. Only this launcher and the detector see the scene's truth; the
mission process is given the operator's ``scenario.json``.

``flight.mcap`` is the MCAP log of the whole flight (``radseek record``, ``radseek_io/mcap_log.py``, run as
one more process of the stack from before the mission starts until it has landed): every zenoh topic of
the run and the vehicle's MAVLink telemetry, which the recorder receives as the GCS on ``--gcs-port``.
Open it in Foxglove or with the ``mcap`` reader; ``radseek replay OUT/flight.mcap`` replays the estimate
from it. ``--no-mcap`` leaves it out (e.g. to keep ``--gcs-port`` for QGroundControl). The dataset stays the
flight's primary record: a recorder that fails is reported on stderr and the flight goes on without it.

A non-empty ``--out`` is refused unless ``--force`` (which removes that folder's previous radseek
outputs first, summaries before data, and leaves other files alone). ``summary.json``, ``report.png``
and ``truth.json`` are written atomically, and only once the vehicle has landed: an aborted run
leaves its recorded frames and logs but no summary.

exit codes:
  0  the search ended on its own criterion with the source located ("source found", or a
     pattern baseline flown to its end with an estimate)
  1  the stack failed: a process exited or did not start (e.g. the zenoh router refused its credentials:
     the process and its own one-line reason are named), the mission failed, or --timeout passed
     (no report)
  2  usage: bad options or scene, or --out is not empty and --force was not given
  3  the search failed: aborted (vehicle failsafe, vehicle landed, ...) or ended without locating the
     source (dwell budget spent, no frontier left, no estimate); dataset, report.png and summary.json
     are still written so the flight can be examined
  4  a team (--vehicles N) located the source, but lost a vehicle on the way (its mission failed or was
     killed): summary.json's per_vehicle marks it failed and keeps the others' results
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import time
from datetime import datetime
from pathlib import Path

from detector_fw_sim.detector_process import LOCKSTEP_TRUTH_WAIT_S
from launch.stack import (
    EXIT_FOUND,
    EXIT_SEARCH_FAILED,
    EXIT_STACK,
    EXIT_USAGE,
    Progress,
    Stack,
    StackRun,
    _last_words,
    _radseek,
    recorder_ready,
    report_verdict,
    start_recorder,
    start_router,
    stop_recorder,
)
from mission.search import STRATEGIES, search_failure
from radseek import topics
from radseek.simclock import ZenohClock

#: what a run writes under --out, summaries and reports first: --force removes them in this order
RUN_OUTPUTS = ("summary.json", "report.png", "flight.mcap", "dataset", "logs", "scenario.json", "scene.json", "zenoh")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="radseek run", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", nargs="?", default=None, help="scene TOML/JSON or bundled name (default: default)")
    p.add_argument("--out", help="output directory (default runs/<time>-<scene>); must be empty unless --force")
    p.add_argument("--force", action="store_true",
                   help="use a non-empty --out: remove its previous run outputs first (other files are kept)")
    speed = p.add_mutually_exclusive_group()
    speed.add_argument("--speedup", type=float, default=20.0, help="sim seconds per wall second (default 20)")
    speed.add_argument("--realtime", action="store_true", help="run at real time (--speedup 1)")
    p.add_argument("--seed", type=int, default=0, help="seed of counts, odometry drift and planner (default 0)")
    p.add_argument("--lockstep", action=argparse.BooleanOptionalAction, default=True,
                   help="the vehicle holds sim time while the mission computes (PX4 SITL lockstep): a pause "
                        "costs no flight time and the same seed flies the same flight (default on)")
    p.add_argument("--instance", type=int, metavar="N",
                   help="fixed ports like PX4 SITL's -i N: zenoh 7447+N, MAVLink API 14540+N, GCS 14550+N (14550 "
                        "with --no-mcap), vehicle local 14580+N,18570+N, system id 1+N (a team of V takes N..N+V-1). "
                        "Without it and without the port flags below, the first free instance 0..9 is used and "
                        "named on stderr (launch/ports.py)")
    p.add_argument("--zenoh-port", type=int, help="router port on 127.0.0.1 (default 7447+N)")
    p.add_argument("--mavlink-port", type=int, help="MAVSDK API port (default 14540+N)")
    p.add_argument("--gcs-port", type=int,
                   help="GCS port for QGroundControl/MAVProxy (default 14550+N; 14550 with --no-mcap)")
    p.add_argument("--vehicle-local-ports", metavar="API,GCS",
                   help="vehicle's own UDP ports (default 14580+N,18570+N)")
    p.add_argument("--mcap", action=argparse.BooleanOptionalAction, default=True,
                   help="record OUT/flight.mcap: every zenoh topic and the MAVLink telemetry, received on --gcs-port "
                        "(default on; --no-mcap leaves that port to a GCS)")
    p.add_argument("--max-dwells", type=int, default=16, help="dwell budget (default 16)")
    p.add_argument("--strategy", default="active", choices=STRATEGIES,
                   help="active search: next dwell by paper 003's eq. 6 (active) or by the information planner (info: "
                        "D-optimal under drift, dwell length by information per second); or a fixed pattern baseline "
                        "(default active)")
    p.add_argument("--timeout", type=float, default=900.0, help="wall seconds before the run is abandoned")
    p.add_argument("--vehicle-arg", action="append", default=[], help="extra argument for radseek vehicle")
    p.add_argument("--detector-arg", action="append", default=[], help="extra argument for radseek detector")
    p.add_argument("--kill-detector-at", type=float, metavar="T",
                   help="fault injection: kill -9 the detector at sim time T and start it again")
    p.add_argument("--vehicles", type=int, default=1, metavar="N",
                   help="fly a team of N vehicles (1..4) on one zenoh router: one mock autopilot, detector and "
                        "mission per vehicle, one joint estimate (launch/run_team.py; default 1)")
    p.add_argument("--kill-mission-at", metavar="VEHICLE:T",
                   help="fault injection with --vehicles N: kill -9 that vehicle's mission process (e.g. uav1:40) "
                        "at its sim time T; the others finish the search")
    p.add_argument("-q", "--quiet", action="store_true", help="no live progress")
    args = p.parse_args(argv)
    speedup = 1.0 if args.realtime else args.speedup
    # refuse what the child processes would refuse, before any of them starts
    if not 0 < speedup <= 1000:
        p.error(f"--speedup {speedup:g} must be in (0, 1000] (the vehicle's range)")
    if args.max_dwells < 1:
        p.error(f"--max-dwells {args.max_dwells} must be >= 1")
    from mission.team import MAX_VEHICLES

    if not 1 <= args.vehicles <= MAX_VEHICLES:
        p.error(f"--vehicles {args.vehicles} must be in 1..{MAX_VEHICLES}")
    if args.vehicles > 1 and args.strategy != "active":
        p.error("--vehicles N flies the active search only (a team's pattern baselines are not built)")
    if args.vehicles == 1 and args.kill_mission_at is not None:
        p.error("--kill-mission-at needs --vehicles N >= 2 (one vehicle's mission is the run)")
    fixed = {name: getattr(args, attr) for name, attr in (("zenoh", "zenoh_port"), ("api", "mavlink_port"),
                                                            ("gcs", "gcs_port")) if getattr(args, attr) is not None}
    if args.vehicle_local_ports is not None:
        try:
            fixed["api_local"], fixed["gcs_local"] = (int(x) for x in args.vehicle_local_ports.split(","))
        except ValueError:
            p.error(f"--vehicle-local-ports {args.vehicle_local_ports!r} must be API,GCS (two port numbers)")

    from detector_fw_sim.scene import SceneError, load_scene
    from launch.ports import PortError, choose
    from radseek_io.outdir import OutputDirError, prepare_output

    try:
        scene = load_scene(args.scene)
    except SceneError as exc:
        print(f"radseek run: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:  # before any process starts (a port in use makes a process die, or join another stack's router) and
        # before --force removes anything
        ports = choose(instance=args.instance, fixed=fixed, n_vehicles=args.vehicles, record=args.mcap)
    except PortError as exc:
        print(f"radseek run: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        out = Path(args.out or f"runs/{datetime.now():%Y%m%d-%H%M%S}-{scene.name}")
        try:
            prepare_output(out, force=args.force, outputs=RUN_OUTPUTS)
        except OutputDirError as exc:
            print(f"radseek run: {exc}", file=sys.stderr)
            return EXIT_USAGE
        print(ports.line(args.vehicles), file=sys.stderr)
        if args.vehicles > 1:
            from launch.run_team import run_team

            return run_team(args, scene, out, speedup, ports)
        return _run_one(args, scene, out, speedup, ports)
    finally:
        ports.release()


def _run_one(args, scene, out: Path, speedup: float, ports) -> int:
    from launch.zenoh_auth import stack_env, write_run_credentials
    from radseek.zenoh_session import open_session, session_user
    from radseek_io.dataset import write_json
    from radseek_io.outdir import atomic_write_json

    scenario_file = out / "scenario.json"
    write_json(scenario_file, scene.scenario().to_dict())
    scene_file = out / "scene.json"
    scene_file.write_text(scene.model_dump_json(indent=2))
    endpoint = ports.endpoint
    port = ports.vehicle(0)
    credentials = write_run_credentials(out, [topics.DEFAULT_VEHICLE], endpoint)
    stack = Stack(out / "logs", env=stack_env(credentials))
    if threading.current_thread() is threading.main_thread():
        # SIGTERM (kill, CI cancelling a job) stops the stack like Ctrl-C does, instead of orphaning it
        signal.signal(signal.SIGTERM, lambda signum, _frame: sys.exit(128 + signum))
    print(f"radseek run: scene {scene.name!r}, speed-up {speedup:g}, output {out}", file=sys.stderr)
    t0 = time.monotonic()
    with StackRun(stack, out) as run:
        start_router(stack, ports)  # (radseek record gives up if no router answers within 3 s)
        if args.mcap:
            start_recorder(stack, out, endpoint, port["gcs"])
        detector_cmd = _radseek(
            "detector", "--scene", str(scene_file), "--clock", "zenoh", "--seed", str(args.seed),
            "--connect", endpoint, *(("--truth-wait", str(LOCKSTEP_TRUTH_WAIT_S)) if args.lockstep else ()),
            *args.detector_arg)
        stack.start("detector", detector_cmd)
        # the log holds the whole flight: the recorder records before the vehicle (sim time) starts
        recorder = recorder_ready(stack, out) if args.mcap else None
        # the vehicle owns sim time: start it only once the detector has built its response and is
        # waiting for the clock, and the mission is up and recording (its first mission/state follows its
        # subscriptions), so no simulated time passes unmeasured, however slowly the processes start
        stack.wait_for_line("detector", "waiting for", timeout_s=180.0)
        with open_session(connect=endpoint, user=session_user(credentials=credentials)) as session:
            mission_up = threading.Event()
            state_sub = session.declare_subscriber(topics.key(topics.MISSION_STATE, topics.DEFAULT_VEHICLE),
                                                   lambda _sample: mission_up.set())
            mission = stack.start("mission", _radseek(
                "mission", "--scenario", str(scenario_file), "--out", str(out / "dataset"), "--connect", endpoint,
                "--url", f"udpin://0.0.0.0:{port['api']}", "--seed", str(args.seed),
                "--speedup", str(speedup), "--max-dwells", str(args.max_dwells), "--strategy", args.strategy))
            ready_by = time.monotonic() + 180.0
            while not mission_up.wait(0.1):
                if mission.poll() is not None:
                    raise RuntimeError(stack.exited("mission"))
                if time.monotonic() > ready_by:
                    raise RuntimeError(f"mission did not get ready in 180 s: see {out}/logs/mission.log")
            state_sub.undeclare()
            stack.start("vehicle", _radseek(
                "vehicle", "--speedup", str(speedup), "--seed", str(args.seed), "--connect", endpoint,
                "--api-port", str(port["api"]), "--gcs-port", str(port["gcs"]),
                "--api-local-port", str(port["api_local"]), "--gcs-local-port", str(port["gcs_local"]),
                "--sysid", str(port["sysid"]), "--max-speed", "1.0",
                "--lockstep" if args.lockstep else "--no-lockstep", *args.vehicle_arg))
            progress = None if args.quiet else Progress(session, topics.DEFAULT_VEHICLE)
            clock = ZenohClock(session, topics.DEFAULT_VEHICLE)
            kill_at = args.kill_detector_at
            try:
                while mission.poll() is None:
                    if kill_at is not None and clock.now() >= kill_at:
                        os.killpg(stack.procs["detector"].pid, signal.SIGKILL)
                        stack.procs["detector"].wait(10)
                        print(f"radseek run: fault injected: detector killed at t={clock.now():.1f} s, restarting",
                              file=sys.stderr)
                        stack.start("detector-restarted", detector_cmd)
                        stack.procs["detector"] = stack.procs.pop("detector-restarted")
                        kill_at = None
                    if time.monotonic() - t0 > args.timeout:
                        print(f"radseek run: abandoned after {args.timeout:g} s wall", file=sys.stderr)
                        break
                    for name, proc in stack.procs.items():
                        if name not in ("mission", "recorder") and proc.poll() is not None:
                            raise RuntimeError(stack.exited(name))
                    if recorder is not None and recorder.poll() is not None:  # the flight goes on without it
                        stop_recorder(stack, out)
                        recorder = None
                    time.sleep(0.2)
            finally:
                if progress:
                    progress.close()
            if recorder is not None:  # the mission has landed: finish the log before the summary
                stop_recorder(stack, out)
    if run.exit_code is not None:
        return run.exit_code
    wall = time.monotonic() - t0
    if mission.returncode not in (EXIT_FOUND, EXIT_SEARCH_FAILED):  # the mission's own verdict is read below
        print(f"radseek run: mission failed (exit {mission.returncode}){_last_words(out / 'logs' / 'mission.log')}; "
              f"see {out}/logs/mission.log", file=sys.stderr)
        return EXIT_STACK
    try:
        mission_summary = json.loads((out / "dataset" / "mission_summary.json").read_text())
    except (OSError, ValueError) as exc:
        print(f"radseek run: the mission left no summary ({exc}); see {out}/logs/mission.log", file=sys.stderr)
        return EXIT_STACK
    failure = search_failure(mission_summary)
    if (mission.returncode == EXIT_SEARCH_FAILED) != (failure is not None):
        print(f"radseek run: the mission's exit code {mission.returncode} disagrees with its summary "
              f"({mission_summary.get('reason')!r})", file=sys.stderr)
    atomic_write_json(out / "dataset" / "truth.json", scene.truth().to_dict())
    from launch.report import write_report

    return report_verdict(lambda: write_report(out, wall_time_s=wall, speedup=speedup), out, failure, "flight is")
