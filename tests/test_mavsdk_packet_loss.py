"""The mission protocol under injected packet loss: the vehicle drops 10 % of datagrams in each
direction (``--drop-rate 0.1``); MAVSDK's uploads and downloads must still complete exactly, through
the vehicle's request retransmission and MAVSDK's own retries."""

import asyncio

import pytest

from mission.client import action, connection, mission_upload
from mission.client.mission_upload import DwellPoint, build_items
from vehicle_sim.harness import VehicleProcess, free_udp_port

pytestmark = pytest.mark.slow


def key(items):
    return [(i.seq, i.command, i.x, i.y, round(i.z, 3), i.param1) for i in items]


async def session(api_port: int) -> dict:
    conn = await connection.connect(f"udpin://127.0.0.1:{api_port}", timeout_s=60)
    out = {"uploads": 0, "exact": 0, "failures": []}
    try:
        home = await connection.wait_healthy(conn, timeout_s=60)
        mc = mission_upload.MissionControl(conn)
        for k in range(3):
            pts = [DwellPoint(float(j), float(k), 3.0, max_dwell_s=float(j)) for j in range(20)]
            items = build_items(pts, home, takeoff_alt=3.0, finish="land")
            try:
                await mc.upload(items)
                out["uploads"] += 1
                out["exact"] += key(await mc.download()) == key(items)
            except mission_upload.MissionFailed as exc:
                out["failures"].append(str(exc))
        # and a short flight to completion over the lossy link
        await mc.upload(build_items([DwellPoint(4.0, 0.0, 3.0, max_dwell_s=1.0)], home, takeoff_alt=3.0,
                                    finish="land"))
        await action.Actions(conn).arm()
        await mc.start()
        await mc.wait_finished(timeout_s=60)
        out["finished"] = True
    finally:
        await conn.close()
    return out


def test_mission_transfer_survives_ten_percent_loss():
    api = free_udp_port()
    with VehicleProcess(api, free_udp_port(), ["--speedup", "20", "--drop-rate", "0.1", "--seed", "2"]) as vp:
        out = asyncio.run(asyncio.wait_for(session(api), 400))  # bounds waiting only
    assert out["failures"] == [] and out["uploads"] == 3 and out["exact"] == 3
    assert out["finished"]
    # the loss really happened: the vehicle reports its counters on exit
    counters = vp.output.rsplit("vehicle stopped", 1)[1].split()
    rx, dropped_rx = int(counters[counters.index("rx") + 1]), int(counters[counters.index("dropped-rx") + 1])
    print(f"vehicle: received {rx}, dropped {dropped_rx} incoming datagrams")
    assert 0.05 < dropped_rx / (rx + dropped_rx) < 0.15
