"""Two `radseek run`s started together while the default ports are taken (zenoh 7447 and MAVLink 14540 held here):
both must move off them and off each other. Flown once per test run (whichever worker asks first, holding the
``default-ports-7447-14540`` lock) for the tests that read them: tests/test_run_ports.py (the moves, the ports line,
no cross-talk) and tests/test_one_world.py (the second is its lattice-wall flight, compared with the in-process
driver's: it flew a run of its own, ~11 s of CPU). A fast honest configuration: lockstep, 50x, the default scene
for 2 dwells (seed 0) and lattice-wall for 3 (seed 1); the MCAP recorder runs (one more subscriber: it changes no
flight).
"""

from __future__ import annotations

import re
import socket
import subprocess
import sys
import threading

import pytest

from launch import ports as P
from tests.support.once_per_run import once_per_run

RUN_TIMEOUT_S = 900
#: (scene, seed, dwell budget) of the two runs
RUNS = (("default", 0, 2), ("lattice-wall", 1, 3))


class Held:
    """A socket holding a default port (TCP listening or UDP bound on 127.0.0.1) that notes who reaches it: the
    owning process of each TCP connection (from ``ss -tnp``, with its parent then: the run's children are gone when
    the test checks) and the source of each datagram. ``sock`` is None if another program already holds the port
    (then it is taken all the same)."""

    def __init__(self, kind: int, port: int):
        self.kind, self.reached = kind, []
        self.sock = socket.socket(socket.AF_INET, kind)
        if kind == socket.SOCK_STREAM:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # a TIME_WAIT is no holder
        try:
            self.sock.bind(("127.0.0.1", port))
        except OSError:
            self.sock.close()
            self.sock = None
            return
        if kind == socket.SOCK_STREAM:
            self.sock.listen()
        self.sock.settimeout(0.2)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, daemon=True)
        self._thread.start()

    def _watch(self) -> None:
        while not self._stop.is_set():
            try:
                if self.kind == socket.SOCK_STREAM:
                    conn, peer = self.sock.accept()
                    owner = subprocess.run(["ss", "-tnpH", f"sport = :{peer[1]}"], capture_output=True,
                                           text=True).stdout
                    pids = [int(x) for x in re.findall(r"pid=(\d+)", owner)]
                    self.reached.append((peer, [(pid, _ppid(pid)) for pid in pids]))
                    conn.close()
                else:
                    _, peer = self.sock.recvfrom(65535)
                    self.reached.append((peer, []))
            except OSError:
                continue

    def close(self) -> None:
        if self.sock is not None:
            self._stop.set()
            self._thread.join(5)
            self.sock.close()


def _ppid(pid: int) -> int | None:
    try:
        return int(open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[1])
    except (OSError, ValueError, IndexError):
        return None


def _run(out, scene: str, seed: int, dwells: int) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "radseek_cli", "run", scene, "--out", str(out), "--quiet", "--speedup", "50",
           "--max-dwells", str(dwells), "--seed", str(seed), "--timeout", str(RUN_TIMEOUT_S)]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def side_by_side_on_held_defaults(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The two runs (``RUNS``) started together while the caller holds the default zenoh and MAVLink API ports:
    ``outs``, ``codes``, ``errs`` (stderr), ``pids``, and who reached the held ports (``tcp``: connections with
    their owners' pids and parents, ``udp``: datagrams' sources)."""

    def fly(folder) -> dict:
        held = [Held(socket.SOCK_STREAM, P.ZENOH_BASE), Held(socket.SOCK_DGRAM, P.API_BASE)]
        try:
            outs = [folder / "a", folder / "b"]
            procs = [_run(out, *run) for out, run in zip(outs, RUNS, strict=True)]  # together: the lock decides
            errs = [p.communicate(timeout=RUN_TIMEOUT_S + 120)[1] for p in procs]
        finally:
            for h in held:
                h.close()
        return {"outs": outs, "codes": [p.returncode for p in procs], "errs": errs, "pids": [p.pid for p in procs],
                "tcp": held[0].reached, "udp": held[1].reached}

    return once_per_run(tmp_path_factory, "run-ports-side-by-side", fly)
