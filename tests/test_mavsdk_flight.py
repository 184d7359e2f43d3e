"""Interoperability: MAVSDK (through radseek's mission client) flies the mock vehicle process over real
UDP: connect, health, telemetry, raw mission upload/download, QGC .plan round trip, arm, dwell points
ended early by advancing the current item, mission replaced in flight, landing."""

import asyncio
import json
import math

import numpy as np
import pytest

from mission.client import action, connection, mission_upload, telemetry
from mission.client.mission_upload import DwellPoint, build_items
from mission.qgc_plan import write_plan
from vehicle_sim.harness import VehicleProcess, free_udp_port

pytestmark = pytest.mark.slow
SPEEDUP = 20.0


async def fly(api_port: int, tmp_path) -> dict:
    conn = await connection.connect(f"udpin://127.0.0.1:{api_port}", timeout_s=60)
    out: dict = {}
    try:
        home = await connection.wait_healthy(conn, timeout_s=60)
        out["home"] = home
        tel = telemetry.TelemetryWatch(conn)
        act = action.Actions(conn)
        mc = mission_upload.MissionControl(conn)
        out["start_pos"] = await tel.position_enu()
        out["battery0"] = await tel.battery_remaining()
        out["mode0"] = await tel.flight_mode()

        points = [DwellPoint(8.0, 0.0, 3.0, yaw=0.0, max_dwell_s=600.0), DwellPoint(8.0, 8.0, 3.0, max_dwell_s=2.0)]
        items = build_items(points, home, takeoff_alt=3.0, finish="land")
        t0 = asyncio.get_running_loop().time()
        await mc.upload(items)
        out["upload_s"] = asyncio.get_running_loop().time() - t0
        down = await mc.download()
        out["round_trip"] = [(i.command, i.x, i.y, i.param1) for i in down] == \
            [(i.command, i.x, i.y, i.param1) for i in items]
        plan = write_plan(tmp_path / "m.plan", items, home)
        imported = await mc._mr.import_qgroundcontrol_mission(str(plan))
        out["plan_items"] = [(i.command, i.x, i.y) for i in imported.mission_items]
        out["plan_json"] = json.loads(plan.read_text())

        await act.arm()
        t_start = asyncio.get_running_loop().time()
        await mc.start()
        await mc.wait_item(1, timeout_s=60)
        pos = await tel.wait_position(lambda p: np.linalg.norm(p - [8, 0, 3]) < 0.3, timeout_s=60)
        out["dwell1_pos"] = pos
        await asyncio.sleep(0.5)  # 10 sim s into a 600 s dwell: still holding
        out["holding"] = (await mc.progress())[0]
        await mc.end_dwell()  # the dwell controller has enough counts
        out["after_end"] = (await mc.progress())[0]
        # the planner re-planned: replace the rest of the mission while flying
        await mc.replace_remaining([DwellPoint(0.0, 8.0, 3.0, max_dwell_s=1.0)], finish="land")
        await tel.wait_position(lambda p: np.linalg.norm(p[:2] - [0, 8]) < 0.3, timeout_s=60)
        await mc.wait_finished(timeout_s=60)
        await tel.wait_in_air(False, timeout_s=60)
        out["flight_wall_s"] = asyncio.get_running_loop().time() - t_start
        out["end_pos"] = await tel.position_enu()
        out["battery1"] = await tel.battery_remaining()
    finally:
        await conn.close()
    return out


def test_mavsdk_flies_a_mission_with_adaptive_dwell(tmp_path):
    api = free_udp_port()
    with VehicleProcess(api, free_udp_port(), ["--speedup", str(SPEEDUP)]) as vp:
        out = asyncio.run(asyncio.wait_for(fly(api, tmp_path), 400))  # bounds waiting only
    print(f"MAVSDK: upload of 4 items {out['upload_s'] * 1000:.0f} ms, flight {out['flight_wall_s']:.1f} s wall "
          f"at x{SPEEDUP:g}, landed at {np.round(out['end_pos'], 2)}, battery {out['battery1']:.3f}")
    assert out["home"].lat_deg == pytest.approx(47.397742, abs=1e-6)
    assert np.linalg.norm(out["start_pos"]) < 0.1
    assert out["battery0"] == pytest.approx(1.0, abs=0.01) and out["mode0"] == "HOLD"
    assert out["round_trip"]
    assert [c for c, _, _ in out["plan_items"]] == [22, 16, 16, 21]
    first_dwell = out["plan_json"]["mission"]["items"][1]
    assert first_dwell["params"][0] == 600.0 and first_dwell["params"][3] == pytest.approx(90.0)  # hold, yaw east
    assert first_dwell["params"][4] == pytest.approx(out["plan_items"][1][1] / 1e7, abs=2e-7)
    assert out["holding"] == 1 and out["after_end"] == 2
    assert np.linalg.norm(out["end_pos"][:2] - [0, 8]) < 0.5 and abs(out["end_pos"][2]) < 0.1
    assert out["battery1"] < out["battery0"]
    assert " bad 0 " in vp.output  # MAVSDK sent nothing the vehicle could not parse
    assert math.isfinite(out["dwell1_pos"][0])
