"""A stack started by hand, as the README lists it (router, detector, vehicle, in that order and bare), runs on
one clock: the detector follows the vehicle's sim/clock by default and its frames carry true poses. A detector on a
clock of its own says, repeatedly, that its frames have no pose and how to fix it. Real processes, a real zenoh
router on loopback; assertions on flags and log lines, wall time only bounds the waiting."""

from __future__ import annotations

import pytest

from radseek import topics
from radseek.zenoh_session import open_session
from tests.conftest import free_port
from tests.test_clock_jumps import WAIT_S, Histograms
from tests.test_detector_stream import Proc

pytestmark = [pytest.mark.slow, pytest.mark.io, pytest.mark.timeout(600)]


def test_bare_detector_then_bare_vehicle_share_the_vehicles_clock(router):
    hists = Histograms()
    with open_session(connect=router) as session:
        sub = session.declare_subscriber(topics.key(topics.HISTOGRAM), hists)
        det = Proc("detector", "--connect", router, "--seed", "2")  # no --clock: auto
        veh = None
        try:
            det.wait_line("waiting for", timeout=WAIT_S)
            veh = Proc("vehicle", "--connect", router, "--speedup", "5", "--api-port", str(free_port()),
                       "--gcs-port", str(free_port()), "--api-local-port", "0", "--gcs-local-port", "0")
            line = det.wait_line("publishing", timeout=WAIT_S)
            assert "clock zenoh" in line
            h = hists.wait(lambda h: h.t >= 2.0 and not h.flags & topics.FLAG_STALE_POSE, "with a true pose")
            assert h.t >= 2.0
        finally:
            det.stop()
            if veh is not None:
                veh.stop()
            sub.undeclare()


def test_a_detector_on_its_own_clock_without_poses_warns_with_the_fix(router):
    det = Proc("detector", "--connect", router, "--clock", "own", "--speedup", "5", "--seed", "3")
    try:
        line = det.wait_line("WARNING", timeout=WAIT_S)
        assert "no true pose" in line and "--clock zenoh" in line
    finally:
        det.stop()
