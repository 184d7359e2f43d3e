"""Interoperability: MAVProxy (headless, on the GCS port) lists the geofence and the rally points an API
client uploaded as the FENCE and RALLY mission types, item by item (`fence list`, `rally list`).

Driven by what MAVProxy prints, as in test_mavproxy.py: no fixed sleeps."""


import pytest
from pymavlink.dialects.v20 import common as M

from tests.support.mavproxy import WAIT_S, MavProxy
from vehicle_sim.harness import Gcs, VehicleProcess, free_udp_port

pytestmark = pytest.mark.slow
LAT, LON = 47.397742, 8.545594


def _item(seq, cmd, lat, lon, p1, mission_type, z=0.0, frame=M.MAV_FRAME_GLOBAL_INT):
    return M.MAVLink_mission_item_int_message(1, 1, seq, frame, cmd, 0, 1, p1, 0, 0, 0, int(round(lat * 1e7)),
                                              int(round(lon * 1e7)), z, mission_type)


def _upload(gcs: Gcs, items: list, mission_type: int) -> int:
    gcs.send(M.MAVLink_mission_count_message(1, 1, len(items), mission_type))
    while True:
        m = gcs.recv({"MISSION_REQUEST_INT", "MISSION_ACK"}, lambda m: m.mission_type == mission_type, WAIT_S)
        if m.get_type() == "MISSION_ACK":
            return m.type
        gcs.send(items[m.seq])


def test_mavproxy_lists_fence_and_rally():
    api, gcs_port = free_udp_port(), free_udp_port()
    square = [(-1e-3, -1e-3), (1e-3, -1e-3), (1e-3, 1e-3), (-1e-3, 1e-3)]
    fence = [_item(k, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, LAT + a, LON + b, 4, 1)
             for k, (a, b) in enumerate(square)]
    fence.append(_item(4, M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, LAT + 2e-4, LON, 5.0, 1))
    rally = [_item(0, M.MAV_CMD_NAV_RALLY_POINT, LAT + 1e-4, LON + 1e-4, 0, 2, 5.0,
                   M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)]
    with VehicleProcess(api, gcs_port, ["--speedup", "5"]), Gcs(api) as api_client:
        api_client.wait_vehicle()
        assert _upload(api_client, fence, 1) == M.MAV_MISSION_ACCEPTED
        assert _upload(api_client, rally, 2) == M.MAV_MISSION_ACCEPTED
        with MavProxy(gcs_port) as mp:
            mp.wait_for("Detected vehicle 1:1", "vehicle detected")
            mp.send("fence list")
            mp.wait_for(lambda out: sum(ln.startswith("500") for ln in out.splitlines()) >= 5, "5 fence items")
            mp.send("rally list")
            mp.wait_for(lambda out: any(ln.startswith("5100 ") for ln in out.splitlines()), "the rally point")
    out = mp.output
    print(out)
    assert "Requesting 5 fence items" in out and "Requesting 1 rally items" in out
    listed = [ln.split() for ln in out.splitlines() if ln.startswith(("500", "5100 "))]
    assert [int(f[0]) for f in listed] == [5001] * 4 + [5004, 5100]
    assert float(listed[2][2]) == pytest.approx(LAT + 1e-3, abs=1e-7) and listed[0][5] == "p1=4.0"
    assert float(listed[5][4]) == pytest.approx(5.0) and listed[5][1] == "6"
