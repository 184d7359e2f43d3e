"""Interoperability: MAVProxy's `takeoff 5` (MAV_CMD_NAV_TAKEOFF with 5 in param7, which PX4 reads as AMSL) is
accepted as PX4 accepts it: an altitude below home + MIS_TAKEOFF_ALT is raised to that minimum, announced with
PX4's "Using minimum takeoff altitude" (navigator/takeoff.cpp). MAVProxy is driven by what it prints."""


import pytest

from tests.support.mavproxy import WAIT_S, MavProxy
from vehicle_sim.harness import Gcs, VehicleProcess, free_udp_port

pytestmark = [pytest.mark.slow, pytest.mark.io]


def test_mavproxy_takeoff_5_climbs_to_the_minimum_takeoff_altitude():
    api, gcs_port = free_udp_port(), free_udp_port()
    with VehicleProcess(api, gcs_port, ["--speedup", "5"]), Gcs(api) as api_client:
        api_client.wait_vehicle()
        with MavProxy(gcs_port) as mp:
            mp.wait_for("Detected vehicle 1:1", "vehicle detected")
            mp.send("arm throttle")
            mp.wait_for("ARMED")
            mp.send("takeoff 5")
            mp.wait_for("Using minimum takeoff altitude: 2.50 m")
            pos = api_client.recv("LOCAL_POSITION_NED", lambda m: m.z < -2.4, timeout=WAIT_S)
            later = [api_client.recv("LOCAL_POSITION_NED", timeout=WAIT_S) for _ in range(30)]
    out = mp.output
    assert "NAV_TAKEOFF: ACCEPTED" in out
    assert pos.z < -2.4
    assert all(-2.6 < m.z < -2.4 for m in later[-10:])  # holds at MIS_TAKEOFF_ALT (2.5 m), not 5 m
