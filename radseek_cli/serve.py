"""Process lifetime for the long-running inspection tools (record, view, topics, echo)."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, TypeVar

if TYPE_CHECKING:
    import zenoh

T = TypeVar("T")

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
    print(started(server), flush=True)
    serve_until_stopped(args.duration)
    summary = stop(server)
    session.close()
    if summary is not None:
        print(summary, flush=True)
    return 0


def serve_until_stopped(duration_s: float | None = None) -> None:
    """Block until SIGTERM, Ctrl-C or ``duration_s`` wall seconds (None: no limit), whichever comes first."""
    stop = threading.Event()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        stop.wait(duration_s)
    except KeyboardInterrupt:
        pass
