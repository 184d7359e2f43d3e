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
  1  the stack failed: a process exited or did not start, the mission failed, or --timeout passed
     (no report)
  2  usage: bad options or scene, or --out is not empty and --force was not given
  3  the search failed: aborted (vehicle failsafe, vehicle landed, ...) or ended without locating the
     source (dwell budget spent, no frontier left, no estimate); dataset, report.png and summary.json
     are still written so the flight can be examined
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from datetime import datetime
from pathlib import Path

from estimator.inflight import sigma_m
from mission.search import STRATEGIES, search_failure
from radseek import topics
from radseek.simclock import ZenohClock

PY = sys.executable

EXIT_FOUND, EXIT_STACK, EXIT_USAGE, EXIT_SEARCH_FAILED = 0, 1, 2, 3
#: what a run writes under --out, summaries and reports first: --force removes them in this order
RUN_OUTPUTS = ("summary.json", "report.png", "flight.mcap", "dataset", "logs", "scenario.json", "scene.json")
#: wall seconds the MCAP recorder may take to start, and to finish its file once stopped
RECORDER_START_S, RECORDER_STOP_S = 60.0, 60.0


def print_summary(summary: dict, out: Path, stdout=None, stderr=None) -> None:
    """The run's verdict line (JSON on stdout) and its warnings (e.g. a failed goodness of fit: the model
    misses something, run ``radseek diagnose``) and where the report is (stderr)."""
    stdout, stderr = stdout or sys.stdout, stderr or sys.stderr
    print(json.dumps({k: summary.get(k) for k in ("error_m", "sigma_m", "bound_m", "dwell_points", "mission_time_s")},
                     default=float), file=stdout)
    for warning in summary.get("warnings", []):
        print(f"radseek run: warning: {warning}", file=stderr)
    print(f"report: {out / 'report.png'}  summary: {out / 'summary.json'}", file=stderr)


def _radseek(*args: str) -> list[str]:
    return [PY, "-m", "radseek_cli", *args]


#: libc loaded in the parent: the child only makes one foreign call between fork and exec
_LIBC = ctypes.CDLL(None, use_errno=True) if sys.platform.startswith("linux") else None
_PR_SET_PDEATHSIG = 1


def _die_with_parent(parent: int):
    """A ``preexec_fn`` that asks Linux to SIGTERM the child when ``parent`` dies (prctl PR_SET_PDEATHSIG):
    a ``radseek run`` killed with SIGKILL cannot stop its stack itself, and its processes would fly on."""

    def hook() -> None:
        if _LIBC is None:
            return
        _LIBC.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
        if os.getppid() != parent:  # the parent died before the request took effect
            os.kill(os.getpid(), signal.SIGTERM)

    return hook


class Stack:
    """The processes of one run; each logs to its own file and is stopped on exit (and, on Linux, when the
    run itself is killed: :func:`_die_with_parent`)."""

    def __init__(self, logs: Path):
        self.logs = logs
        self.logs.mkdir(parents=True, exist_ok=True)
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self, name: str, cmd: list[str]) -> subprocess.Popen:
        fh = open(self.logs / f"{name}.log", "w")  # noqa: SIM115 (closed with the process)
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        proc = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, env=env, start_new_session=True,
                                preexec_fn=_die_with_parent(os.getpid()))
        self.procs[name] = proc
        return proc

    def wait_for_line(self, name: str, text: str, timeout_s: float) -> None:
        """Block until process ``name`` has logged ``text`` (RuntimeError if it exits or times out)."""
        deadline = time.monotonic() + timeout_s
        log = self.logs / f"{name}.log"
        while time.monotonic() < deadline:
            if text in log.read_text(errors="replace"):
                return
            if self.procs[name].poll() is not None:
                raise RuntimeError(f"{name} exited with {self.procs[name].returncode}: see {log}")
            time.sleep(0.05)
        raise RuntimeError(f"{name} did not get ready in {timeout_s:g} s: see {log}")

    def stop(self) -> None:
        for name in reversed(list(self.procs)):
            proc = self.procs[name]
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGTERM)
        deadline = time.monotonic() + 10.0  # one grace period for the whole stack, not 10 s per process
        for proc in self.procs.values():
            wait_or_kill(proc, max(deadline - time.monotonic(), 0.1))


def wait_or_kill(proc: subprocess.Popen, timeout_s: float) -> bool:
    """Wait up to ``timeout_s`` for ``proc`` to exit, else SIGKILL its process group; True if it exited by
    itself (``timeout_s`` 0: kill it now unless it has already exited)."""
    try:
        proc.wait(timeout_s)
        return True
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(5)
        return False


def _warn_no_mcap(out: Path, why: str) -> None:
    print(f"radseek run: warning: {why}; see {out / 'logs' / 'recorder.log'} (the flight goes on: dataset/ is "
          "its record)", file=sys.stderr)


def _last_words(log: Path) -> str:
    """': ' and the log's last line when it is the process's own error message ("radseek ...: ..."), else ''."""
    try:
        lines = log.read_text(errors="replace").strip().splitlines()
    except OSError:
        return ""
    last = next((ln.strip() for ln in reversed(lines) if ln.strip()), "")
    return f": {last}" if last.startswith("radseek ") else ""


def start_recorder(stack: Stack, out: Path, endpoint: str, gcs_port: int) -> None:
    """Start ``radseek record`` into ``out/flight.mcap``: every zenoh topic, and the MAVLink the vehicle
    sends its GCS port (the recorder is that GCS: it listens and never answers)."""
    stack.start("recorder", _radseek("record", "--out", str(out / "flight.mcap"), "--connect", endpoint,
                                     "--mavlink-port", str(gcs_port)))


def recorder_ready(stack: Stack, out: Path) -> subprocess.Popen | None:
    """The recorder once it records; None, said on stderr, when it did not start (the flight goes on)."""
    try:
        stack.wait_for_line("recorder", "recording", timeout_s=RECORDER_START_S)
    except RuntimeError as exc:
        wait_or_kill(stack.procs.pop("recorder"), 0.0)
        _warn_no_mcap(out, f"no flight.mcap: the recorder did not start ({exc})")
        return None
    return stack.procs["recorder"]


def stop_recorder(stack: Stack, out: Path) -> bool:
    """Stop the recorder (SIGTERM: it finishes the MCAP file, footer and index) and say on stderr if it
    failed; True when flight.mcap is complete."""
    proc = stack.procs.pop("recorder", None)
    if proc is None:
        return False
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        if not wait_or_kill(proc, RECORDER_STOP_S):
            _warn_no_mcap(out, f"the recorder did not finish {out / 'flight.mcap'} in {RECORDER_STOP_S:g} s and was "
                               "killed: the file is truncated")
            return False
    else:
        _warn_no_mcap(out, f"the recorder stopped during the flight (exit {proc.returncode}): "
                           f"{out / 'flight.mcap'} is incomplete")
        return False
    if proc.returncode != 0 or "wrote" not in (out / "logs" / "recorder.log").read_text(errors="replace"):
        _warn_no_mcap(out, f"the recorder failed to finish {out / 'flight.mcap'} (exit {proc.returncode})")
        return False
    return True


class Progress:
    """Live one-line display from ``mission/state`` and ``estimate``."""

    def __init__(self, session, vehicle: str, stream=sys.stderr, label: str = ""):
        self.stream = stream
        self.label = label  # a team's lines start with the vehicle's name
        self.state: topics.MissionState | None = None
        self.estimate: topics.Estimate | None = None
        self.lock = threading.Lock()
        self._subs = [session.declare_subscriber(topics.key(name, vehicle), self._keeping(attr, schema))
                      for name, attr, schema in ((topics.MISSION_STATE, "state", topics.MissionState),
                                                 (topics.ESTIMATE, "estimate", topics.Estimate))]
        self._last = ""

    def _keeping(self, attr: str, schema):
        """A subscriber callback that keeps the latest valid ``schema`` message in ``attr`` and redraws
        (an invalid one is ignored: the display shows what it can)."""
        def on_sample(sample) -> None:
            try:
                msg = schema.from_bytes(sample.payload.to_bytes())
            except topics.PayloadError:
                return
            with self.lock:
                setattr(self, attr, msg)
            self.show()
        return on_sample

    def show(self) -> None:
        with self.lock:
            st, est = self.state, self.estimate
        if st is None:
            return
        line = (f"{self.label}: " if self.label else "") + \
            f"[t={st.t:6.1f}s] {st.phase:<8s} dwell {st.dwell_index:>2d}  battery {100 * st.battery:3.0f}%"
        if est is not None and est.sources:
            s = est.sources[0]
            cov = est.covariance_block(0)
            sig = sigma_m(cov)  # the in-flight estimate's one definition (inf: not trustworthy yet)
            line += f"  estimate ({s['x']:.2f}, {s['y']:.2f}) m  {s['cps_at_1m']:.0f} cps@1m  sigma {sig:.2f} m"
        line += f"  {st.progress}"
        if line != self._last:
            self._last = line
            print(line[:160], file=self.stream, flush=True)

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()


class StackRun:
    """``with StackRun(stack, out) as run:`` the processes' flight. A stack failure (RuntimeError,
    TimeoutError) or Ctrl-C is said on stderr and kept as ``run.exit_code`` (None: the flight went through);
    the stack is stopped whatever happened."""

    def __init__(self, stack: Stack, out: Path):
        self.stack, self.out = stack, out
        self.exit_code: int | None = None

    def __enter__(self) -> StackRun:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            if exc_type is not None and issubclass(exc_type, (RuntimeError, TimeoutError)):
                print(f"radseek run: {exc}", file=sys.stderr)
                self.exit_code = EXIT_STACK
                return True
            if exc_type is not None and issubclass(exc_type, KeyboardInterrupt):
                print(f"radseek run: interrupted; the frames recorded so far are in {self.out / 'dataset'} "
                      "(no summary)", file=sys.stderr)
                self.exit_code = 128 + signal.SIGINT
                return True
            return False
        finally:
            self.stack.stop()


def report_verdict(write_report: Callable[[], dict], out: Path, failure: str | None, recorded: str) -> int:
    """Write the report (``write_report``: the summary) and print the summary, then the run's exit code from
    the search's ``failure`` (None: found). A report that fails is said on stderr with where the ``recorded``
    flight is; without a report a search that found the source is a stack failure."""
    try:
        summary = write_report()
    except Exception as exc:  # noqa: BLE001 - a flight too short to fit still has a verdict and its data
        print(f"radseek run: no report ({type(exc).__name__}: {exc}); the recorded {recorded} in {out / 'dataset'}",
              file=sys.stderr)
        if failure is None:
            return EXIT_STACK
    else:
        print_summary(summary, out)
    if failure is not None:
        print(f"radseek run: search failed: {failure}", file=sys.stderr)
        return EXIT_SEARCH_FAILED
    return EXIT_FOUND


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
                   help="active search (paper 003) or a fixed pattern baseline (default active)")
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


def start_router(stack: Stack, ports) -> None:
    """Start the router and wait until it listens; a port taken meanwhile is said with the flag that moves it."""
    stack.start("router", _radseek("router", "--listen", ports.endpoint))
    try:
        stack.wait_for_line("router", "listening", timeout_s=60.0)
    except RuntimeError as exc:
        if "already in use" in (stack.logs / "router.log").read_text(errors="replace"):
            raise RuntimeError(f"zenoh port {ports.zenoh} was taken before the router could listen (another "
                               "stack?): run again (free ports are picked again), or give --instance N or "
                               "--zenoh-port PORT") from exc
        raise


def _run_one(args, scene, out: Path, speedup: float, ports) -> int:
    from radseek.zenoh_session import open_session
    from radseek_io.dataset import write_json
    from radseek_io.outdir import atomic_write_json

    scenario_file = out / "scenario.json"
    write_json(scenario_file, scene.scenario().to_dict())
    scene_file = out / "scene.json"
    scene_file.write_text(scene.model_dump_json(indent=2))
    endpoint = ports.endpoint
    port = ports.vehicle(0)
    stack = Stack(out / "logs")
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
            "--connect", endpoint, *(("--truth-wait", "0.5") if args.lockstep else ()), *args.detector_arg)
        stack.start("detector", detector_cmd)
        # the log holds the whole flight: the recorder records before the vehicle (sim time) starts
        recorder = recorder_ready(stack, out) if args.mcap else None
        # the vehicle owns sim time: start it only once the detector has built its response and is
        # waiting for the clock, and the mission is up and recording (its first mission/state follows its
        # subscriptions), so no simulated time passes unmeasured, however slowly the processes start
        stack.wait_for_line("detector", "waiting for", timeout_s=180.0)
        with open_session(connect=endpoint) as session:
            mission_up = threading.Event()
            state_sub = session.declare_subscriber(topics.key(topics.MISSION_STATE, topics.DEFAULT_VEHICLE),
                                                   lambda _sample: mission_up.set())
            mission = stack.start("mission", _radseek(
                "mission", "--scenario", str(scenario_file), "--out", str(out / "dataset"), "--connect", endpoint,
                "--url", f"udpin://0.0.0.0:{port['api']}", "--seed", str(args.seed),
                "--max-dwells", str(args.max_dwells), "--strategy", args.strategy))
            ready_by = time.monotonic() + 180.0
            while not mission_up.wait(0.1):
                if mission.poll() is not None:
                    raise RuntimeError(f"mission exited with {mission.returncode}: see {out}/logs/mission.log")
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
                            raise RuntimeError(f"{name} exited with {proc.returncode}: see {out}/logs/{name}.log")
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
