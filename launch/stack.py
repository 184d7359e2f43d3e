"""The process stack of ``radseek run`` (one vehicle, ``radseek_cli.run_cli``) and of a team run (``launch.run_team``):
starting and stopping the processes, the router and the MCAP recorder, live progress, and the verdict's exit code.

Both launchers import this module and neither imports the other at module level (``run_cli`` hands a team
run to ``run_team``): the pieces they share live here so that the two do not import each other.
"""

from __future__ import annotations

import ctypes
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

from estimator.inflight import sigma_m
from radseek import topics

PY = sys.executable

EXIT_FOUND, EXIT_STACK, EXIT_USAGE, EXIT_SEARCH_FAILED = 0, 1, 2, 3
#: a team found the source, but one of its vehicles was lost on the way (``per_vehicle`` marks which)
EXIT_FOUND_VEHICLE_LOST = 4
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

    def __init__(self, logs: Path, env: dict[str, str] | None = None):
        self.logs = logs
        self.logs.mkdir(parents=True, exist_ok=True)
        self.procs: dict[str, subprocess.Popen] = {}
        self.env = env or {}  # on top of the launcher's environment (the run's zenoh credentials)

    def start(self, name: str, cmd: list[str]) -> subprocess.Popen:
        fh = open(self.logs / f"{name}.log", "w")  # noqa: SIM115 (closed with the process)
        env = {**os.environ, **self.env, "PYTHONUNBUFFERED": "1"}
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
                raise RuntimeError(self.exited(name))
            time.sleep(0.05)
        raise RuntimeError(f"{name} did not get ready in {timeout_s:g} s: see {log}")

    def exited(self, name: str) -> str:
        """One line: process ``name`` exited, with its own last words (e.g. the router refused it) and its log."""
        log = self.logs / f"{name}.log"
        return f"{name} exited with {self.procs[name].returncode}{_last_words(log)}; see {log}"

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


def start_recorder(stack: Stack, out: Path, endpoint: str, gcs_port: int | None = None,
                   gcs_ports: dict[str, int] | None = None) -> None:
    """Start ``radseek record`` into ``out/flight.mcap``: every zenoh topic, and the MAVLink the vehicle
    sends its GCS port (the recorder is that GCS: it listens and never answers); a team's, each vehicle's
    GCS port (``gcs_ports`` by vehicle name). ``out/scenario.json``, when the launcher wrote it, gives the
    walls drawn for Foxglove."""
    ports = ([] if gcs_port is None else [str(gcs_port)]) + [f"{n}={p}" for n, p in (gcs_ports or {}).items()]
    scenario = ["--scenario", str(out / "scenario.json")] if (out / "scenario.json").is_file() else []
    stack.start("recorder", _radseek("record", "--out", str(out / "flight.mcap"), "--connect", endpoint, *scenario,
                                     *(a for p in ports for a in ("--mavlink-port", p))))


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
            # the MCAP log is finished first, with its own grace: stopped with the rest of the stack under one
            # 10 s grace, a loaded machine's recorder was killed before it wrote its buffer (an aborted run's
            # flight.mcap held no magic in a 2-worker CI run)
            stop_recorder(self.stack, self.out)
            self.stack.stop()


def report_verdict(write_report: Callable[[], dict], out: Path, failure: str | None, recorded: str) -> int:
    """Write the report (``write_report``: the summary) and print the summary, then the run's exit code from
    the search's ``failure`` (None: found; found by a team that lost a member on the way: 4). A report that
    fails is said on stderr with where the ``recorded`` flight is; without a report a search that found the
    source is a stack failure."""
    summary = None
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
    lost = [] if summary is None else [r["vehicle"] for r in summary.get("per_vehicle", []) if r.get("failed")]
    if lost:
        print(f"radseek run: source found, with {' and '.join(lost)} lost (summary.json per_vehicle)", file=sys.stderr)
        return EXIT_FOUND_VEHICLE_LOST
    return EXIT_FOUND


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
