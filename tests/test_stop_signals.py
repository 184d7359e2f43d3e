"""The long-running tools stop on SIGTERM whichever of their threads the kernel hands it to.

The kernel delivers a process's signal to any thread that does not block it. Sent with kill(2) to one thread's id it
prefers that thread: here one of zenoh's, as happened by chance under load (a router once ignored SIGTERM for over a
minute, holding a test's teardown). Each tool must still stop, and cleanly (exit 0).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from radseek_cli.serve import serve_until_stopped
from tests.conftest import free_port

pytestmark = pytest.mark.io

WAIT_S = 60.0  # bound on waiting for a process to start or stop (a loaded host is slow), never asserted


def _other_threads(pid: int) -> list[int]:
    return sorted(int(t) for t in os.listdir(f"/proc/{pid}/task") if int(t) != pid)


def _stop_via_another_thread(proc: subprocess.Popen, sig: int) -> int | None:
    """Send ``sig`` to each of ``proc``'s threads but its main one (a non-main thread takes it) until it exits;
    its exit status, None if it did not exit within WAIT_S."""
    deadline = time.monotonic() + WAIT_S
    threads = _other_threads(proc.pid)
    assert threads, "the tool runs zenoh's threads beside its main one"
    os.kill(threads[-1], sig)
    try:
        return proc.wait(max(deadline - time.monotonic(), 0.1))
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        return None


def _start(args: list[str], ready: str, log: Path) -> subprocess.Popen:
    with log.open("w") as out:
        proc = subprocess.Popen([sys.executable, "-m", "radseek_cli", *args], stdout=out, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + WAIT_S
    while ready not in log.read_text():
        assert proc.poll() is None and time.monotonic() < deadline, log.read_text()
        time.sleep(0.02)
    return proc


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_the_router_stops_on_a_signal_a_zenoh_thread_took(tmp_path, sig):
    log = tmp_path / "router.log"
    proc = _start(["router", "--listen", f"tcp/127.0.0.1:{free_port()}"], "listening", log)
    assert _stop_via_another_thread(proc, sig) == 0, log.read_text()


def test_topics_stops_on_a_sigterm_a_zenoh_thread_took(tmp_path, router):
    """`radseek topics --duration 600` (a long listen) stops on SIGTERM at once and still prints its table."""
    proc = _start(["topics", "--duration", "600", "--connect", router], "listening to", tmp_path / "topics.log")
    assert _stop_via_another_thread(proc, signal.SIGTERM) == 0, (tmp_path / "topics.log").read_text()
    assert "no messages on" in (tmp_path / "topics.log").read_text()


def test_a_signal_sent_as_soon_as_the_ready_line_is_out_stops_the_wait_cleanly():
    """A launcher may send SIGTERM the instant it reads the "listening" line: the handler must already be in place
    (topics once printed that line first and died by the signal, exit -15, under load)."""
    previous = signal.getsignal(signal.SIGTERM)
    served = []
    serve_until_stopped(600.0, ready=lambda: (served.append(True), os.kill(os.getpid(), signal.SIGTERM)))
    assert served == [True]
    assert signal.getsignal(signal.SIGTERM) is previous  # the tool's handler is gone once it stops waiting
