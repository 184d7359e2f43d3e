"""MAVProxy, headless, as the GCS of a vehicle under test: started on the vehicle's GCS port, driven by what it
prints (each command sent once the output it depends on has appeared, never after a fixed sleep), stopped by
closing its input. Shared by the MAVProxy interoperability tests."""

import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

MAVPROXY = Path(sys.executable).parent / "mavproxy.py"
WAIT_S = 60.0  # bounds waiting only


class MavProxy:
    """``with MavProxy(gcs_port) as mp: mp.send(...); mp.wait_for(cond, what)``; ``mp.output`` is all it printed
    (also after the ``with``)."""

    def __init__(self, gcs_port: int, cwd: Path | None = None):
        exe = str(MAVPROXY) if MAVPROXY.exists() else shutil.which("mavproxy.py")
        assert exe, "MAVProxy missing: `make` installs it with pip --no-deps (see Makefile)"
        self._cmd = [exe, f"--master=udpin:127.0.0.1:{gcs_port}", "--no-state"]
        self._cwd = cwd
        self._lines: list[str] = []

    @property
    def output(self) -> str:
        return "".join(self._lines)

    def __enter__(self) -> "MavProxy":
        self._proc = subprocess.Popen(self._cmd, cwd=self._cwd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, text=True,
                                      env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self._reader = threading.Thread(target=lambda: self._lines.extend(self._proc.stdout), daemon=True)
        self._reader.start()
        return self

    def send(self, command: str) -> None:
        self._proc.stdin.write(command + "\n")
        self._proc.stdin.flush()

    def wait_for(self, cond, what: str = "") -> None:
        """Wait until ``cond(output)`` (a string: until it is printed); fails naming ``what`` (default: the
        string) if MAVProxy exits or ``WAIT_S`` passes."""
        what = what or repr(cond)
        test = (lambda out: cond in out) if isinstance(cond, str) else cond
        deadline = time.monotonic() + WAIT_S
        while not test(self.output):
            assert self._proc.poll() is None, f"MAVProxy exited waiting for {what}:\n{self.output}"
            assert time.monotonic() < deadline, f"MAVProxy: no {what} in {WAIT_S} s:\n{self.output}"
            time.sleep(0.05)

    def __exit__(self, *exc) -> None:
        self._proc.stdin.close()
        try:
            self._proc.wait(30)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        self._reader.join(10)
