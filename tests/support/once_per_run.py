"""A module fixture's value computed once per test run, not once per xdist worker.

`make test` hands tests out one at a time (``--maxschedchunk 1``), so a module's tests land on both workers and a
``scope="module"`` fixture is built on each: a calibration fit or a whole diagnose call paid twice. The pytest-xdist
recipe ("making session-scoped fixtures execute only once"): the first worker computes under a file lock in the
run's shared temporary folder and pickles the value; the others wait for the lock and load it.
"""

from __future__ import annotations

import fcntl
import pickle
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import pytest

T = TypeVar("T")


def shared_folder(tmp_path_factory: pytest.TempPathFactory, name: str) -> Path:
    """A folder every worker of this run sees (the parent of the workers' own base temp folders)."""
    root = tmp_path_factory.getbasetemp()
    if root.name.startswith("popen-gw"):  # under xdist each worker has its own base below the run's
        root = root.parent
    out = root / f"once-{name}"
    out.mkdir(exist_ok=True)
    return out


def once_per_run(tmp_path_factory: pytest.TempPathFactory, name: str, compute: Callable[[Path], T]) -> T:
    """``compute(folder)`` in the first worker that asks (``folder``: where it may write files the value points
    at), its pickled value loaded by the others."""
    folder = shared_folder(tmp_path_factory, name)
    with (folder / "lock").open("a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            done = folder / "value.pickle"
            if done.exists():
                return pickle.loads(done.read_bytes())
            value = compute(folder)
            tmp = folder / "value.pickle.tmp"
            tmp.write_bytes(pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL))
            tmp.replace(done)
            return value
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)
