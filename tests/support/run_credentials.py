"""The per-run zenoh credentials of a `radseek run` started by a test, once it has written them."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

from radseek.zenoh_auth import read_credentials


def wait_for_credentials(out: Path, run: subprocess.Popen, timeout_s: float = 300.0) -> list:
    """The users `radseek run --out OUT` generated (OUT/zenoh/credentials), read once the file exists and the
    router it configures has had a moment to start (the file is written whole before the router starts)."""
    path = out / "zenoh" / "credentials"
    deadline = time.monotonic() + timeout_s
    while not path.is_file() and run.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    time.sleep(0.5)
    return read_credentials(path)
