"""Process lifetime for the long-running inspection tools (record, view, topics, echo)."""

from __future__ import annotations

import argparse
import os
import select
import signal
import sys
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, TypeVar

if TYPE_CHECKING:
    import zenoh

T = TypeVar("T")

#: the signals that stop a long-running tool (SIGTERM from a launcher, SIGINT from Ctrl-C)
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)
ROUTER_WAIT_S = 3.0  # s: an inspection tool says at once that no router answers, instead of waiting silently


def open_session_or_report(prog: str, args: argparse.Namespace, wait_for_router_s: float = ROUTER_WAIT_S,
                           user: str | None = None) -> zenoh.Session | None:
    """The zenoh session the command line asks for (``radseek.zenoh_session`` options; a reader, as the
    credentials' ``user`` when given), or None after printing ``<prog>: <why>`` on stderr (no router
    answered, the config file does not exist, the router refused the credentials)."""
    from radseek.zenoh_session import OPEN_ERRORS, session_from_args  # zenoh only once a tool really connects

    try:
        return session_from_args(args, prefer=user, wait_for_router_s=wait_for_router_s)
    except OPEN_ERRORS as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return None


def serve_on_session(prog: str, args: argparse.Namespace, start: Callable[[zenoh.Session], T],
                     errors: type[Exception] | tuple[type[Exception], ...], explain: Callable[[Exception], str], *,
                     started: Callable[[T], str], stop: Callable[[T], str | None], user: str | None = None) -> int:
    """The life of a tool that serves the live topics until stopped (``radseek view``, ``radseek record``).

    Opens the session (as ``open_session_or_report``), starts ``start(session)`` on it (a server, a recorder:
    it binds a port), prints ``started(server)``, serves until SIGTERM, Ctrl-C or ``args.duration`` wall
    seconds, then calls ``stop(server)``, closes the session and prints what ``stop`` returned (if not None).
    Exit status 0, or 1 after printing ``<prog>: <why>`` on stderr when there is no session or ``start``
    raises one of ``errors`` (the session is closed; ``explain(exc)`` is the why).
    """
    session = open_session_or_report(prog, args, user=user)
    if session is None:
        return 1
    try:
        server = start(session)
    except errors as exc:
        session.close()
        print(f"{prog}: {explain(exc)}", file=sys.stderr)
        return 1
    serve_until_stopped(args.duration, ready=lambda: print(started(server), flush=True))
    summary = stop(server)
    session.close()
    if summary is not None:
        print(summary, flush=True)
    return 0


class StopSignals:
    """SIGTERM and Ctrl-C (SIGINT), noted from the moment this is entered (in the main thread) until it exits.

    They are noted on a pipe that Python's C-level signal handler writes to (``signal.set_wakeup_fd``), not by an
    event a Python handler sets: the kernel hands a process's signal to any thread that does not block it, often
    one of zenoh's, and then only that thread notes it; the main thread, asleep in a lock's wait, was never woken
    (a router ignored SIGTERM for over a minute under load; sent to one of zenoh's threads it never stopped)."""

    def __enter__(self) -> StopSignals:
        self._main = threading.current_thread() is threading.main_thread()
        if self._main:  # signals reach only the main thread's handlers: elsewhere this waits for the time alone
            self._r, self._w = os.pipe()
            os.set_blocking(self._w, False)
            self._previous = {sig: signal.signal(sig, lambda *_: None) for sig in STOP_SIGNALS}
            self._old_fd = signal.set_wakeup_fd(self._w, warn_on_full_buffer=False)
        return self

    def wait(self, timeout_s: float | None = None) -> bool:
        """True once a stop signal has come (at once if one came since entering), False after ``timeout_s``
        seconds without one (None: no limit)."""
        if not self._main:
            threading.Event().wait(timeout_s)
            return False
        ready, _, _ = select.select([self._r], [], [], timeout_s)  # retried after a signal (PEP 475)
        return bool(ready)

    def __exit__(self, *exc: object) -> None:
        if self._main:
            signal.set_wakeup_fd(self._old_fd)
            for sig, handler in self._previous.items():
                signal.signal(sig, handler)
            os.close(self._r)
            os.close(self._w)


def serve_until_stopped(duration_s: float | None = None, ready: Callable[[], None] | None = None) -> None:
    """Block until SIGTERM, Ctrl-C or ``duration_s`` wall seconds (None: no limit), whichever comes first.

    ``ready()`` (a tool's "listening" line) is called once the signals are caught, never before: a launcher that
    sends SIGTERM as soon as it reads that line must get a clean stop, not Python's default death by the signal."""
    with StopSignals() as stop:
        if ready is not None:
            ready()
        stop.wait(duration_s)
