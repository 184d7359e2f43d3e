"""A Co-60 second source beside the Cs-137 primary on a flight of the independent generator (benchmarks/forward2:
lawnmower, a made-up "wide" crystal, scattered photons, independent pose errors), and its whole diagnose call
(~25 s of CPU), made once per test run for the tests that read it: tests/test_diagnose_second_nuclide_verdict.py
(the nuclide, the spectral verdict with and without it) and tests/test_diagnose_verdict.py (the JSON report names
it)."""

from __future__ import annotations

import pytest

from benchmarks.forward2 import FlightSpec, simulate
from estimator.diagnose.runner import diagnose
from tests.support.once_per_run import once_per_run

SPEC = FlightSpec(geometry="lawnmower", crystal="wide", scatter=0.02, pose_error="independent",
                  effects={"second_source": {"x": 1.5, "y": 1.5, "z": 0.0, "cps_at_1m": 1300.0, "nuclide": "Co-60"}})


def co60_second_diagnosis(tmp_path_factory: pytest.TempPathFactory):
    """(dataset, diagnosis) of the flight (seed 90021, 4 starts)."""

    def run(_folder):
        ds = simulate(SPEC, seed=90021)
        return ds, diagnose(ds, quiet=True, n_starts=4)

    return once_per_run(tmp_path_factory, "co60-second", run)
