"""``radseek run --vehicles N`` (N = 2..4): a team on one zenoh router, one joint search (issue 18).

Per vehicle ``uav<v>``: a mock autopilot (``radseek vehicle``: PX4 instance N + v of the run's instance N,
``launch/ports.py``: MAVLink system id N + v + 1, API port 14540 + N + v, GCS port 14550 + N + v, local ports
14580 + N + v and 18570 + N + v; a port given by its flag replaces the base, e.g. ``--mavlink-port`` + v; its own
odometry seed ``--seed`` + 1000 v, launch point ``mission.team.home_positions``), a detector (its own count
seed) and a mission process (``radseek mission --team``: MAVSDK on its vehicle's port, the team brain of
``mission.team`` fed with every vehicle's frames). The missions announce their reservations and dwells on
``radseek/<vehicle>/team/status`` and publish the joint estimate on ``radseek/team/estimate``; the vehicle
whose estimate ends the search says so there and the others end theirs; each vehicle lands where it is.

Output (``--out``): ``dataset/uav<v>/`` (each vehicle's recorded flight, its ``mission_summary.json`` and
``truth.json``), ``report.png`` (every vehicle's path and dwells, the joint estimate), ``summary.json``
(``error_m``, ``sigma_m``, ``mission_time_s`` of the joint estimate that ended the search, plus
``per_vehicle``: one {vehicle, dwell_points, distance_m, failed} per vehicle), ``flight.mcap`` (every zenoh
topic; MAVLink of uav0), ``logs/``.

A member that fails (its mission crashed, was killed, or recorded nothing) costs the team nothing else: the
report and ``summary.json`` are written from the others, the member marked ``failed``, and a search the others
ended with the source located exits 4 ("found, with a vehicle lost"; ``radseek run --help``).

``--kill-mission-at uav1:T`` (fault injection): SIGKILL that vehicle's mission process when its clock passes
T sim seconds; its vehicle's own failsafes take over (lockstep released, link loss: hold, then RTL), the
others finish the search. That vehicle alone releases lockstep after ``KILLED_LOCKSTEP_TIMEOUT_S`` of silence
instead of the vehicle's default 5 s, so the team learns of the loss while it still searches; the live
missions' vehicles keep the default (a shorter one released a live but busy mission's vehicle on a loaded
machine).
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

from detector_fw_sim.detector_process import LOCKSTEP_TRUTH_WAIT_S
from launch.stack import (
    EXIT_FOUND,
    EXIT_SEARCH_FAILED,
    EXIT_STACK,
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
from mission.search import search_failure
from mission.team import MAX_VEHICLES, TeamConfig, home_positions
from radseek import topics

#: wall s of lockstep silence after which the vehicle of a mission killed by ``--kill-mission-at`` runs free
KILLED_LOCKSTEP_TIMEOUT_S = 1.0


def vehicle_names(n: int) -> list[str]:
    return [f"uav{v}" for v in range(n)]


def parse_kill(text: str | None, names: list[str]) -> tuple[str, float] | None:
    """``--kill-mission-at VEHICLE:T`` -> (vehicle, T); ValueError on a bad one."""
    if text is None:
        return None
    name, _, t = text.partition(":")
    if name not in names:
        raise ValueError(f"--kill-mission-at {text!r}: vehicle must be one of {', '.join(names)}")
    try:
        at = float(t)
    except ValueError:
        raise ValueError(f"--kill-mission-at {text!r}: T must be sim seconds") from None
    if not at >= 0:
        raise ValueError(f"--kill-mission-at {text!r}: T must be >= 0")
    return name, at


def team_verdict(summaries: dict[str, dict]) -> tuple[str | None, dict | None]:
    """The vehicle whose estimate ended the team's search and its summary (else the first that has one)."""
    for name, s in summaries.items():
        if s.get("decided"):
            return name, s
    for name, s in summaries.items():
        return name, s
    return None, None


def run_team(args, scene, out: Path, speedup: float, ports) -> int:
    """The team flight on ``ports`` (``launch.ports.Ports``: vehicle v on PX4 instance N + v)."""
    from launch.zenoh_auth import stack_env, write_run_credentials
    from radseek.simclock import ZenohClock
    from radseek.zenoh_session import open_session, session_user
    from radseek_io.dataset import write_json
    from radseek_io.outdir import atomic_write_json

    n = int(args.vehicles)
    names = vehicle_names(n)
    try:
        kill = parse_kill(args.kill_mission_at, names)
    except ValueError as exc:
        print(f"radseek run: {exc}", file=sys.stderr)
        return 2
    scenario = scene.scenario()
    homes = home_positions(scenario, TeamConfig(n_vehicles=n))
    scenario_file = out / "scenario.json"
    write_json(scenario_file, scenario.to_dict())
    scene_file = out / "scene.json"
    scene_file.write_text(scene.model_dump_json(indent=2))
    endpoint = ports.endpoint
    port = [ports.vehicle(v) for v in range(n)]
    credentials = write_run_credentials(out, names, endpoint)
    stack = Stack(out / "logs", env=stack_env(credentials))
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, lambda signum, _frame: sys.exit(128 + signum))
    print(f"radseek run: scene {scene.name!r}, {n} vehicles, speed-up {speedup:g}, output {out}", file=sys.stderr)
    t0 = time.monotonic()
    missions: dict[str, object] = {}
    killed: dict[str, float] = {}
    with StackRun(stack, out) as run:
        start_router(stack, ports)
        if args.mcap:
            start_recorder(stack, out, endpoint, gcs_ports={name: port[v]["gcs"] for v, name in enumerate(names)})
        for v, name in enumerate(names):
            stack.start(f"detector-{name}", _radseek(
                "detector", "--scene", str(scene_file), "--clock", "zenoh", "--seed", str(args.seed + 1000 * v),
                "--connect", endpoint, "--vehicle-name", name,
                *(("--truth-wait", str(LOCKSTEP_TRUTH_WAIT_S)) if args.lockstep else ()), *args.detector_arg))
        recorder = recorder_ready(stack, out) if args.mcap else None
        for name in names:
            stack.wait_for_line(f"detector-{name}", "waiting for", timeout_s=180.0)
        with open_session(connect=endpoint, user=session_user(credentials=credentials)) as session:
            up = {name: threading.Event() for name in names}
            subs = [session.declare_subscriber(topics.key(topics.MISSION_STATE, name),
                                               lambda _s, e=up[name]: e.set()) for name in names]
            for v, name in enumerate(names):
                missions[name] = stack.start(f"mission-{name}", _radseek(
                    "mission", "--scenario", str(scenario_file), "--out", str(out / "dataset" / name),
                    "--connect", endpoint, "--vehicle-name", name, "--team", ",".join(names),
                    "--url", f"udpin://0.0.0.0:{port[v]['api']}", "--seed", str(args.seed + 1000 * v),
                    "--speedup", str(speedup), "--max-dwells", str(args.max_dwells), "--strategy", args.strategy))
            ready_by = time.monotonic() + 180.0
            for name in names:
                while not up[name].wait(0.1):
                    if missions[name].poll() is not None:
                        raise RuntimeError(stack.exited(f"mission-{name}"))
                    if time.monotonic() > ready_by:
                        raise RuntimeError(f"mission {name} did not get ready in 180 s")
            for s in subs:
                s.undeclare()
            for v, name in enumerate(names):
                stack.start(f"vehicle-{name}", _radseek(
                    "vehicle", "--speedup", str(speedup), "--seed", str(args.seed + 1000 * v), "--connect", endpoint,
                    "--vehicle-name", name, "--sysid", str(port[v]["sysid"]),
                    "--api-port", str(port[v]["api"]), "--gcs-port", str(port[v]["gcs"]),
                    "--api-local-port", str(port[v]["api_local"]), "--gcs-local-port", str(port[v]["gcs_local"]),
                    f"--start={homes[v][0]:g},{homes[v][1]:g}", "--max-speed", "1.0",
                    "--lockstep" if args.lockstep else "--no-lockstep", *args.vehicle_arg,
                    *(("--lockstep-timeout", str(KILLED_LOCKSTEP_TIMEOUT_S)) if kill and kill[0] == name else ())))
            clocks = {name: ZenohClock(session, name) for name in names}
            shows = [] if args.quiet else [Progress(session, name, label=name) for name in names]
            while any(m.poll() is None for m in missions.values()):
                if kill is not None and clocks[kill[0]].now() >= kill[1]:
                    proc = missions[kill[0]]
                    if proc.poll() is None:
                        os.killpg(proc.pid, signal.SIGKILL)
                        proc.wait(10)
                    killed[kill[0]] = clocks[kill[0]].now()
                    print(f"radseek run: fault injected: mission {kill[0]} killed at t={killed[kill[0]]:.1f} s",
                          file=sys.stderr)
                    kill = None
                if time.monotonic() - t0 > args.timeout:
                    print(f"radseek run: abandoned after {args.timeout:g} s wall", file=sys.stderr)
                    break
                for pname, proc in stack.procs.items():
                    if not pname.startswith(("mission", "recorder")) and proc.poll() is not None:
                        raise RuntimeError(stack.exited(pname))
                if recorder is not None and recorder.poll() is not None:
                    stop_recorder(stack, out)
                    recorder = None
                time.sleep(0.2 if kill is None else 0.01)  # a pending kill watches the clock closely
            if recorder is not None:
                stop_recorder(stack, out)
            for show in shows:
                show.close()
    if run.exit_code is not None:
        return run.exit_code
    wall = time.monotonic() - t0
    summaries: dict[str, dict] = {}
    for name in names:
        if name in killed:
            continue
        code = missions[name].returncode
        if code not in (EXIT_FOUND, EXIT_SEARCH_FAILED):
            print(f"radseek run: mission {name} failed (exit {code})"
                  f"{_last_words(out / 'logs' / f'mission-{name}.log')}; see {out}/logs/mission-{name}.log",
                  file=sys.stderr)
            continue
        try:
            summaries[name] = json.loads((out / "dataset" / name / "mission_summary.json").read_text())
        except (OSError, ValueError) as exc:
            print(f"radseek run: mission {name} left no summary ({exc})", file=sys.stderr)
    decider, verdict = team_verdict(summaries)
    if verdict is None:
        print("radseek run: no mission of the team finished", file=sys.stderr)
        return EXIT_STACK
    failure = search_failure(verdict)
    for name in names:
        if (out / "dataset" / name / "frames.csv").exists():
            atomic_write_json(out / "dataset" / name / "truth.json", scene.truth().to_dict())
    from launch.report import write_team_report

    return report_verdict(lambda: write_team_report(out, names, decider, killed=killed, wall_time_s=wall,
                                                    speedup=speedup), out, failure, "flights are")


__all__ = ["MAX_VEHICLES", "parse_kill", "run_team", "team_verdict", "vehicle_names"]
