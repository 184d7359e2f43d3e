"""diagnose's forked fit workers never run a finalizer of the caller's garbage (``CountFitter.fit_many``): a cycle
left unreachable in the calling process is collected there, where its threads live. In a make test a forked
worker collected such a cycle (an earlier test's), whose finalizer waited on a thread the fork had not copied, and
spun for 8 minutes."""

from __future__ import annotations

import gc
import os

import pytest

from benchmarks.forward2 import FlightSpec, simulate
from estimator.diagnose.backend import CountFitter, FitTask


class _Cycle:
    """Half of a reference cycle: only the cyclic collector frees it, in whichever process runs a collection."""

    def __init__(self, log: str, creator: int):
        self.log, self.creator, self.other = log, creator, None

    def __del__(self):
        if os.getpid() != self.creator:
            with open(self.log, "a") as fh:
                fh.write(f"{os.getpid()}\n")


@pytest.mark.io  # forks its worker processes
def test_forked_fit_workers_do_not_finalize_the_callers_garbage(tmp_path):
    flight = simulate(FlightSpec(geometry="lattice"), seed=5)
    fitter = CountFitter(flight.scenario, flight.frames, n_starts=1, quiet=True, jobs=2)
    log = str(tmp_path / "finalized-in-a-worker")
    held = []
    # 50 cycles, reachable through `held` while a full collection moves them to the oldest generation, then let go:
    # garbage the caller's young collections do not look at, so it is still there when the workers are forked
    for _ in range(50):
        a, b = _Cycle(log, os.getpid()), _Cycle(log, os.getpid())
        a.other, b.other = b, a
        held.append(a)
    del a, b
    gc.collect()
    held.clear()
    # a worker's collection, as fits run them whenever they allocate enough; here asked for (a side call runs in a
    # forked worker beside the fits)
    fits, side = fitter.fit_many([FitTask(("dead_time",)), FitTask(("background_gradient",))],
                                 side={"collect": lambda: (os.getpid(), gc.collect())})
    assert all(f is not None for f in fits) and side["collect"][0] != os.getpid()
    assert not os.path.exists(log), f"a forked worker ran the caller's finalizers: {open(log).read().split()}"
    gc.collect()  # here, in the caller, they are freed as they should be
