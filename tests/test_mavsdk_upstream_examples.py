"""MAVSDK-Python's upstream examples beyond ../shared (github.com/mavlink/MAVSDK-Python, examples/, BSD-3),
unchanged, against `radseek vehicle`: the examples are the copies in tests/mavsdk_upstream/ (byte for byte, with
their licence and source commit), or those of the MAVSDK-Python checkout named by RADSEEK_MAVSDK_PYTHON_EXAMPLES.

They run as tests/test_mavsdk_examples.py runs the shared ones (same runner, same fixed ports 14540 / 50051, so
the same machine-wide lock): a pymavlink listener on the vehicle's GCS port records what the vehicle did."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests import test_mavsdk_examples as ex

pytestmark = [pytest.mark.slow, pytest.mark.io, pytest.mark.exclusive("mavsdk-examples-udp14540-grpc50051")]
UPSTREAM = Path(os.environ.get("RADSEEK_MAVSDK_PYTHON_EXAMPLES", Path(__file__).parent / "mavsdk_upstream"))


@pytest.fixture(autouse=True)
def upstream_examples(monkeypatch):
    if not (UPSTREAM / "failure_injection.py").exists():
        pytest.fail(f"MAVSDK-Python's examples folder not found at {UPSTREAM}: set RADSEEK_MAVSDK_PYTHON_EXAMPLES to "
                    "a checkout's examples/ (git clone https://github.com/mavlink/MAVSDK-Python)")
    monkeypatch.setattr(ex, "EXAMPLES", UPSTREAM)


def test_failure_injection_gps_off():
    # SYS_FAILURE_EN (INT32) set, take off, climb 20 m, GPS off, 20 s later failure injection disabled again
    expect = ["-- Enabling failure injection", "-- Injecting GPS failure", "-- Disabling failure injection"]
    out, w = ex.completes("failure_injection.py", ["--speedup", "5"], expect, runner=ex.sped_up(5))
    assert "Traceback" not in out
    assert any("Failure injected: gps off" in t for t in w.texts)
    assert w.max_alt() > 15.0  # flew up before the failure
    # the receiver, connected without a fix (GPS-denied) before, reports no GPS once failed
    assert w.gps_fix[0] == 1 and w.gps_fix[-1] == 0 and 1 in w.gps_fix[:w.gps_fix.index(0)]
