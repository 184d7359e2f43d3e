"""Tear an embedded Ray cluster down when its driver dies, even by kill -9.

``ray.init(address="local")`` starts GCS, raylet, dashboard, monitors, agents and workers as the driver's
descendants. Killed with SIGKILL, the driver cannot shut them down: GCS and raylet follow it, but
``ray::DashboardAgent`` and ``ray::RuntimeEnvAgent`` were seen alive (and listening) minutes later, orphaned to
init, and the cluster's temporary folder stayed behind. Process groups do not catch them (Ray puts its workers in
groups of their own), and parentage is lost once they are orphaned. What they all keep is the environment they
were started with, so:

- :func:`start_reaper` marks the driver's environment with a token (``RADSEEK_RAY_CLUSTER``) while Ray starts
  (every Ray process inherits it: GCS, raylet and through the raylet the agents and workers) and starts this module
  as a small process in its own session, watching the driver (a pidfd: woken the moment it exits) and a pipe from it.
- When the driver dies, or closes the pipe (:meth:`Reaper.close`, after ``ray.shutdown()``), the reaper SIGKILLs
  every process of this user that holds the token in its initial environment or names the cluster's temporary
  folder (command line, open files: setproctitle overwrites what /proc shows of the agents' environment), until
  none is left, removes the folder and exits.

Only the standard library: it runs as ``python -I ray_reaper.py`` without the project on its path.
"""

from __future__ import annotations

import argparse
import os
import secrets
import select
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

__all__ = ["MARK_ENV", "Reaper", "marked_pids", "reap", "start_reaper"]

MARK_ENV = "RADSEEK_RAY_CLUSTER"
POLL_S = 0.5  # s: how often the parent is checked where pidfds are unavailable
ROUNDS = 20  # sweeps at most: a process being started while the others die is caught by the next one


def marked_pids(token: str, temp_dir: str | None = None, exclude: set[int] = frozenset()) -> list[int]:
    """Processes of this user that belong to the cluster: their initial environment holds ``MARK_ENV=token``, or
    their command line or an open file names ``temp_dir`` (Ray's agents rename themselves with setproctitle, which
    overwrites the environment block /proc shows; their logs stay open in the folder)."""
    needle = f"{MARK_ENV}={token}".encode()
    folder = temp_dir.rstrip("/") + "/" if temp_dir else None
    found = []
    for p in Path("/proc").iterdir():
        if not p.name.isdigit() or int(p.name) in exclude:
            continue
        try:
            if needle in (p / "environ").read_bytes().split(b"\0") or (folder and _uses(p, folder)):
                found.append(int(p.name))
        except OSError:  # gone, or another user's
            continue
    return found


def _uses(proc: Path, folder: str) -> bool:
    """Whether the process ``proc`` (/proc/PID) names ``folder`` in its command line or has a file in it open."""
    if folder.encode() in (proc / "cmdline").read_bytes():
        return True
    for fd in (proc / "fd").iterdir():
        try:
            if os.readlink(fd).startswith(folder):
                return True
        except OSError:
            continue
    return False


def reap(token: str, temp_dir: str | None, exclude: set[int] = frozenset()) -> int:
    """SIGKILL every marked process until none is left, then remove ``temp_dir``; returns how many were killed."""
    killed: set[int] = set()
    for _ in range(ROUNDS):
        pids = marked_pids(token, temp_dir, exclude | {os.getpid()})
        alive = [pid for pid in pids if not _zombie(pid)]
        if not alive:
            break
        for pid in alive:
            try:
                os.kill(pid, signal.SIGKILL)
                killed.add(pid)
            except (ProcessLookupError, PermissionError):
                pass
        time.sleep(0.1)
    if temp_dir:
        shutil.rmtree(temp_dir, ignore_errors=True)
    return len(killed)


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] in ("Z", "X")
    except (OSError, IndexError):
        return True


def _wait(parent: int, pipe: int) -> None:
    """Return when ``parent`` has exited or closed its end of ``pipe``."""
    fds = [pipe]
    pidfd = None
    try:
        pidfd = os.pidfd_open(parent)
        fds.append(pidfd)
    except (AttributeError, OSError):  # no pidfd (old kernel) or the parent is already gone
        if os.getppid() != parent:
            return
    while True:
        ready, _, _ = select.select(fds, [], [], None if pidfd is not None else POLL_S)
        if pidfd is not None and pidfd in ready:
            return
        if pipe in ready and not os.read(pipe, 4096):
            return  # EOF: the driver is done with Ray, or gone
        if pidfd is None and os.getppid() != parent:
            return


class Reaper:
    """The running reaper of one embedded cluster (see the module)."""

    def __init__(self, proc: subprocess.Popen, token: str, temp_dir: str | None):
        self.proc, self.token, self.temp_dir = proc, token, temp_dir

    def close(self, timeout: float = 30.0) -> None:
        """Ray is shut down: let the reaper sweep what is left, remove the folder and exit."""
        if self.proc.stdin is not None and not self.proc.stdin.closed:
            self.proc.stdin.close()
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def start_reaper(temp_dir: str | None) -> Reaper:
    """Start the reaper of the cluster about to be started; the caller puts ``MARK_ENV=reaper.token`` in the
    environment its Ray processes are started with."""
    token = f"{os.getpid()}-{secrets.token_hex(8)}"
    proc = subprocess.Popen([sys.executable, "-I", str(Path(__file__).resolve()), "--parent", str(os.getpid()),
                             "--token", token, *(["--temp-dir", temp_dir] if temp_dir else [])],
                            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)  # Ctrl-C and a hang-up of the terminal are the driver's
    return Reaper(proc, token, temp_dir)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--parent", type=int, required=True)
    p.add_argument("--token", required=True)
    p.add_argument("--temp-dir")
    args = p.parse_args(argv)
    for sig in (signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)
    _wait(args.parent, sys.stdin.fileno())
    reap(args.token, args.temp_dir, exclude={args.parent})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
