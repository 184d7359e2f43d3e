"""Two `radseek run`s of one seed flown at the same time (default scene, 50x, 4 dwells, seed 0, every port free),
once per test run: tests/test_lockstep_repro.py holds that they are the same flight, tests/test_one_world.py that
the first is the in-process driver's flight. A run costs ~12 s of CPU (six processes); each test flew its own."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.conftest import free_port
from tests.support.once_per_run import once_per_run
from vehicle_sim.harness import free_udp_port

RUN_TIMEOUT_S = 900
SEED = 0
MAX_DWELLS = 4
SCENE = "default"


def _cmd(out) -> list[str]:
    return [sys.executable, "-m", "radseek_cli", "run", SCENE, "--out", str(out), "--quiet", "--speedup", "50",
            "--max-dwells", str(MAX_DWELLS), "--seed", str(SEED), "--zenoh-port", str(free_port()),
            "--mavlink-port", str(free_udp_port()), "--gcs-port", str(free_udp_port()),
            "--vehicle-local-ports", f"{free_udp_port()},{free_udp_port()}", "--timeout", str(RUN_TIMEOUT_S)]


def same_seed_runs(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """``{"outs": [a, b], "codes": [...], "errs": [...]}`` of the two runs (started together, so they also compete
    for the CPU differently)."""

    def fly(folder) -> dict:
        outs = [folder / "a", folder / "b"]
        procs = [subprocess.Popen(_cmd(o), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for o in outs]
        results = []
        try:
            for p in procs:
                results.append(p.communicate(timeout=RUN_TIMEOUT_S + 60))
        finally:
            for p in procs:
                if p.poll() is None:
                    p.kill()
                    p.wait()
        return {"outs": outs, "codes": [p.returncode for p in procs], "errs": [err for _, err in results]}

    return once_per_run(tmp_path_factory, "same-seed-runs", fly)
