"""Process lifetime for the long-running inspection tools (record, view, topics, echo)."""

from __future__ import annotations

import signal
import threading


def serve_until_stopped(duration_s: float | None = None) -> None:
    """Block until SIGTERM, Ctrl-C or ``duration_s`` wall seconds (None: no limit), whichever comes first."""
    stop = threading.Event()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        stop.wait(duration_s)
    except KeyboardInterrupt:
        pass
