"""Shared fixtures: the shared reference datasets live beside the repository (../shared/datasets)."""

from __future__ import annotations

import fcntl
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path

import pytest
from hypothesis import settings

from benchmarks.shared_data import shared_path
from tests.support import schedule

if os.environ.get("PYTEST_XDIST_WORKER"):
    # `make test`/`make check` run a pytest-xdist worker per core or more: a worker's BLAS (OpenBLAS) taking a thread
    # per core as well puts two threads on each core, which spin while they wait for each other
    # (test_gain_drift_shapes: 23.4 s of CPU with two threads, 17.6 s with one). Set before numpy is first
    # imported (neither pytest nor hypothesis imports it) and inherited by the processes the tests start.
    for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

# CI is deterministic: every property test draws the same examples on every run (a fuzz test that found a
# new case at random once in a while would block every landing). To explore beyond them, run
# HYPOTHESIS_PROFILE=explore pytest tests/test_fuzz_*.py (new random draws on every run).
settings.register_profile("ci", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False, database=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

# ---- the unit tier (`make check`): no subprocesses, no sockets, no routers
#
# Tests that start a process, open a socket (loopback UDP/TCP, a zenoh session, a websocket) or need a
# router are marked ``io`` (a test using the ``router`` fixture is marked here). `make check` runs
# ``-m "not slow and not io" --unit``; with ``--unit`` the tier polices itself: a test that starts a
# process or opens a socket anyway fails, naming the marker it lacks, so the tier stays fast and free of
# ports as tests are added. `make test` runs everything, marked or not.

IO_REASON = "starts a subprocess, opens a socket or a zenoh session: mark it @pytest.mark.io (README: make check)"


def pytest_addoption(parser):
    parser.addoption("--unit", action="store_true",
                     help="the unit tier (make check): fail any test that starts a subprocess or opens a socket")
    parser.addoption("--record-durations", metavar="FILE",
                     help="write each test of 0.5 s or more with its wall seconds (make durations: the schedule's "
                          "tests/durations.json)")


def pytest_collection_modifyitems(config, items):
    for item in items:
        if "router" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.io)
    if os.environ.get("PYTEST_XDIST_WORKER"):
        # in parallel workers (`make test`: one test at a time, --maxschedchunk 1) the collection order is the
        # schedule: planned longest first on the workers, tests of one exclusive lock not overlapping
        # (tests/support/schedule.py; every worker plans alike, as xdist needs)
        known = schedule.load_durations()

        def expected(item) -> float:
            if item.nodeid in known:
                return known[item.nodeid]
            marked = item.get_closest_marker("slow") or item.get_closest_marker("io")
            return schedule.UNKNOWN_SLOW_S if marked else schedule.UNKNOWN_S

        def lock(item) -> str | None:
            mark = item.get_closest_marker("exclusive")
            return None if mark is None else str(mark.args[0])

        workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
        items[:] = schedule.plan(items, expected, lock, workers)


def pytest_runtest_logreport(report):
    """``--record-durations``: each test's wall seconds (setup, call and teardown) for the schedule."""
    _DURATIONS[report.nodeid] = _DURATIONS.get(report.nodeid, 0.0) + report.duration


def pytest_sessionfinish(session):
    path = session.config.getoption("record_durations", None)
    if path and not os.environ.get("PYTEST_XDIST_WORKER") and _DURATIONS:
        Path(path).write_text(json.dumps({k: round(v, 1) for k, v in sorted(_DURATIONS.items())
                                          if v >= 0.5}, indent=0) + "\n")


_DURATIONS: dict[str, float] = {}


_INHERITED = object()


class _UnitGuard:
    """While a test runs under ``--unit``: every way to start a process or reach a socket records what was
    tried and raises; the test then fails with ``IO_REASON`` even if the code under test swallowed the error
    (or it happened in a thread). What a third-party module does while it is being imported (urllib3's IPv6
    probe binds a socket, ``platform`` runs ``uname -p``) is the library's, not the test's: let through."""

    def __init__(self):
        self.tried: list[str] = []
        self._saved: list[tuple[object, str, object]] = []
        self._lock = threading.Lock()

    def _deny(self, what: str, real):
        def denied(*args, **kwargs):
            frame = sys._getframe(1)
            while frame is not None:
                if frame.f_code.co_filename.startswith("<frozen importlib._bootstrap"):
                    return real(*args, **kwargs)
                frame = frame.f_back
            with self._lock:
                self.tried.append(what)
            raise PermissionError(f"unit tier: {what}: {IO_REASON}")
        return denied

    def _patch(self, owner, name: str, what: str) -> None:
        if hasattr(owner, name):
            real = getattr(owner, name)
            self._saved.append((owner, name, vars(owner).get(name, _INHERITED)))
            setattr(owner, name, self._deny(what, real))

    def start(self) -> None:
        self.tried.clear()
        self._patch(subprocess.Popen, "__init__", "subprocess.Popen")
        for name in ("fork", "forkpty", "posix_spawn", "posix_spawnp", "system", "execv", "execve"):
            self._patch(os, name, f"os.{name}")
        for name in ("bind", "connect", "connect_ex", "sendto", "listen"):
            self._patch(socket.socket, name, f"socket.{name}")
        try:
            import zenoh
        except ImportError:
            zenoh = None
        if zenoh is not None:
            self._patch(zenoh, "open", "zenoh.open")

    def stop(self) -> None:
        while self._saved:
            owner, name, value = self._saved.pop()
            if value is _INHERITED:
                delattr(owner, name)
            else:
                setattr(owner, name, value)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item, nextitem):
    if not item.config.getoption("unit"):
        return (yield)
    guard = item.config.stash.setdefault(_GUARD, _UnitGuard())
    guard.start()
    try:
        return (yield)
    finally:
        guard.stop()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    report = yield
    guard = item.config.stash.get(_GUARD, None)
    if guard is not None and guard.tried and report.when == "call" and not report.skipped:
        report.outcome = "failed"
        report.longrepr = f"unit tier: the test tried {sorted(set(guard.tried))}: {IO_REASON}"
    return report


_GUARD = pytest.StashKey[_UnitGuard]()


# ---- tests that need a fixed port: one at a time on this machine
#
# `make test` runs 2 pytest-xdist workers (and another clone's tests may run beside them). A test marked
# ``exclusive("NAME")`` holds a machine-wide lock NAME (a flock on a file in the temp folder) from before its
# first fixture to after its last, so two tests taking the same fixed port (MAVSDK-Python's examples: 14540
# and gRPC 50051; a local Ray cluster's default ports) never run at the same time, whichever worker or clone
# runs them. (xdist_group is not used: with pytest 9.2, pytest-xdist 3.8 cannot rename the node ids it
# groups by, and silently runs a group on both workers.)


@pytest.fixture(autouse=True)
def _exclusive(request):
    mark = request.node.get_closest_marker("exclusive")
    if mark is None:
        yield
        return
    path = Path(tempfile.gettempdir()) / f"radseek-tests-{mark.args[0]}.lock"
    with path.open("a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)  # waits while another worker's (or clone's) test holds it
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)

REPO = Path(__file__).resolve().parents[1]
SHARED_DATASETS = shared_path("datasets")


def shared_dataset_names() -> list[str]:
    if not SHARED_DATASETS.is_dir():
        return []
    return sorted(p.name for p in SHARED_DATASETS.iterdir() if (p / "frames.csv").exists())


@pytest.fixture(scope="session")
def shared_datasets() -> Path:
    if not SHARED_DATASETS.is_dir():
        pytest.fail(f"shared datasets not found at {SHARED_DATASETS}: clone next to shared/")
    return SHARED_DATASETS


_HANDED_TCP: set[int] = set()


def free_port() -> int:
    """A loopback TCP port free now and not handed out before by this worker (the kernel may reuse one it just
    released, and a test drawing several needs them distinct)."""
    while True:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        if port not in _HANDED_TCP:
            _HANDED_TCP.add(port)
            return port


@pytest.fixture
def router(tmp_path_factory):
    """A real `radseek router` on a free loopback port; yields its endpoint.

    Its output goes to a file, not a pipe nobody reads after the first line: zenoh's threads log there, and one
    blocked on a full pipe would hold up the session's close. A router that ignores SIGTERM for ROUTER_STOP_S is
    killed and said in a warning with its log (one clean-clone make test waited the 60 s it used to allow)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    log = tmp_path_factory.mktemp("router") / "router.log"
    with log.open("w") as out:
        proc = subprocess.Popen([sys.executable, "-m", "radseek_cli", "router", "--listen", endpoint],
                                stdout=out, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 120
        while "listening" not in log.read_text():
            assert proc.poll() is None and time.monotonic() < deadline, f"the router did not start: {log.read_text()}"
            time.sleep(0.02)
        yield endpoint
    finally:
        proc.terminate()
        try:
            proc.wait(ROUTER_STOP_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            warnings.warn(f"radseek router ignored SIGTERM for {ROUTER_STOP_S:g} s and was killed; its log: "
                          f"{log.read_text()[-2000:]}", stacklevel=1)


#: wall seconds a router fixture's router has to exit after SIGTERM (it takes ~0.03 s idle)
ROUTER_STOP_S = 20.0


@pytest.fixture
def counted_fits(monkeypatch):
    """Count the in-flight estimator's fits by their ``n_starts`` (``calls``), and, while ``misfit["on"]``,
    inject the fault of a failed goodness of fit (p = 1e-6) into each fit's result."""
    from estimator.inflight import InflightEstimator

    real_fit = InflightEstimator._fit
    calls: list[int | None] = []
    misfit = {"on": False}

    def fit(self, frames, settings):
        loc = real_fit(self, frames, settings)
        calls.append(settings.get("n_starts"))
        if misfit["on"] and loc is not None:
            loc.info_["p_value"] = 1e-6
        return loc

    monkeypatch.setattr(InflightEstimator, "_fit", fit)
    return calls, misfit
