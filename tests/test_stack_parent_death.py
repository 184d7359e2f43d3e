"""A ``radseek run`` killed with SIGKILL cannot stop its stack: the stack's processes must die with it
(``launch.stack.Stack`` asks Linux for a parent-death signal). Real processes, no mocks."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")

PARENT = """
import sys, time
from pathlib import Path
from launch.stack import Stack
stack = Stack(Path(sys.argv[1]))
child = stack.start("sleeper", [sys.executable, "-c", "import time; time.sleep(600)"])
print(child.pid, flush=True)
time.sleep(600)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as fh:  # a zombie (exited, not yet reaped by init) is not running
        return fh.read().split(")")[-1].split()[0] != "Z"


@pytest.mark.io
def test_stack_processes_die_with_a_killed_run(tmp_path):
    parent = subprocess.Popen([sys.executable, "-c", PARENT, str(tmp_path / "logs")], stdout=subprocess.PIPE,
                              text=True)
    child = int(parent.stdout.readline())
    try:
        assert _alive(child)
        parent.send_signal(signal.SIGKILL)
        parent.wait(30)
        for _ in range(600):  # the kernel signals the child at once; allow a loaded machine 60 s to run it
            if not _alive(child):
                break
            time.sleep(0.1)
        assert not _alive(child), "the stack's process outlived the killed run"
    finally:
        if _alive(child):
            os.kill(child, signal.SIGKILL)
