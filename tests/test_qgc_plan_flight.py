"""QGroundControl .plan files: `radseek plan --export-plan` writes one, `radseek mission --plan` flies one
(mission, geofence and rally points uploaded through MAVSDK's importer) against the vehicle process;
its RTL lands at the rally point, the nearest safe point (PX4 RTL_TYPE 0)."""

import json
import math
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from mission.client.mission_upload import build_items, waypoint
from mission.qgc_plan import PlanError, read_plan, write_plan
from radseek.coordinates import Home, enu_to_geodetic
from vehicle_sim.harness import Gcs, VehicleProcess, free_udp_port


@pytest.mark.io
def test_export_plan_from_the_planner(tmp_path):
    out = tmp_path / "search.plan"
    proc = subprocess.run([sys.executable, "-m", "radseek_cli", "plan", "--method", "lawnmower", "--export-plan",
                           str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(out.read_text())
    cmds = [i["command"] for i in doc["mission"]["items"]]
    assert cmds[0] == 22 and cmds[-1] == 21 and cmds.count(16) >= 2
    assert any(i["params"][0] == 60.0 for i in doc["mission"]["items"])  # dwell holds
    land, last = doc["mission"]["items"][-1], doc["mission"]["items"][-2]
    assert land["params"][4:6] == last["params"][4:6] and abs(land["params"][4]) > 1  # not Null Island
    assert len(doc["geoFence"]["polygons"]) == 1 and doc["geoFence"]["polygons"][0]["inclusion"]
    mission, fence, rally = read_plan(out)
    assert [m.command for m in mission] == cmds and len(fence) == 4 and all(f.param1 == 4 for f in fence)
    assert rally == []
    walled = tmp_path / "walls.plan"
    scene = Path(__file__).resolve().parents[1] / "detector_fw_sim" / "scenes" / "lattice-wall.toml"
    proc = subprocess.run([sys.executable, "-m", "radseek_cli", "plan", "--scene", str(scene), "--method",
                           "lawnmower", "--export-plan", str(walled)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    polygons = json.loads(walled.read_text())["geoFence"]["polygons"]
    assert [p["inclusion"] for p in polygons] == [True, False, False]  # the bounds, then each mapped wall


@pytest.mark.slow
def test_mission_flies_a_plan_with_fence_and_rally(tmp_path):
    home = Home()
    items = build_items([], home, takeoff_alt=3.0)
    items.append(waypoint(1, home, 10.0, 0.0, 3.0))
    items += build_items([], home, finish="rtl")
    items[-1].seq = 2
    rally = enu_to_geodetic(home, (12.0, 4.0, 0.0))
    corners = [enu_to_geodetic(home, c)[:2] for c in ((-30, -30, 0), (30, -30, 0), (30, 30, 0), (-30, 30, 0))]
    plan = write_plan(tmp_path / "m.plan", items, home, polygons=[(True, corners)],
                      rally=[(rally[0], rally[1], 3.0)])
    api, gcs_port = free_udp_port(), free_udp_port()
    with VehicleProcess(api, gcs_port, ["--speedup", "20"]), Gcs(gcs_port) as gcs:
        positions, stop = [], threading.Event()

        def listen():
            while not stop.is_set():
                positions.extend(m for m in gcs.poll(0.05) if m.get_type() == "GLOBAL_POSITION_INT")

        listener = threading.Thread(target=listen, daemon=True)
        listener.start()
        proc = subprocess.run([sys.executable, "-m", "radseek_cli", "mission", "--plan", str(plan), "--url",
                               f"udpin://127.0.0.1:{api}"], capture_output=True, text=True, timeout=400)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        summary = json.loads(proc.stdout.strip().splitlines()[-1])
        assert summary == {"mission_items": 3, "fence_items": 4, "rally_points": 1, "landed": True}
        stop.set()
        listener.join(5)
        last = positions[-1]  # sent once the mission process saw the vehicle landed
    n = math.radians(last.lat / 1e7 - home.lat_deg) * 6378137.0
    e = math.radians(last.lon / 1e7 - home.lon_deg) * 6378137.0 * math.cos(math.radians(home.lat_deg))
    assert math.hypot(e - 12.0, n - 4.0) < 0.5 and last.relative_alt < 200  # landed at the rally point


def _simple(cmd: int, lat: float, lon: float, alt: float, hold: float = 0.0) -> dict:
    return {"type": "SimpleItem", "autoContinue": True, "command": cmd, "doJumpId": 1, "frame": 3,
            "params": [hold, 0, 0, None, lat, lon, alt], "Altitude": alt, "AltitudeMode": 1}


def test_a_survey_complex_item_is_read_as_the_items_qgc_saved_in_it(tmp_path):
    """QGC saves a survey (and a corridor scan) as a ComplexItem holding the SimpleItems it flies
    (TransectStyleComplexItem.Items): read_plan flattens them in order; a structure scan is named, not guessed."""
    lat0, lon0 = 47.3977, 8.5456
    transect = [_simple(16, lat0 + 1e-5 * k, lon0 + 2e-5 * (k % 2), 10.0) for k in range(4)]
    survey = {"type": "ComplexItem", "complexItemType": "survey", "version": 5, "angle": 0,
              "polygon": [[lat0, lon0], [lat0 + 1e-4, lon0], [lat0 + 1e-4, lon0 + 1e-4]],
              "TransectStyleComplexItem": {"version": 1, "Items": transect, "CameraCalc": {"version": 2}}}
    doc = {"fileType": "Plan", "version": 1, "groundStation": "QGroundControl",
           "mission": {"version": 2, "firmwareType": 12, "vehicleType": 2, "plannedHomePosition": [lat0, lon0, 488],
                       "items": [_simple(22, lat0, lon0, 10.0), survey, _simple(21, lat0, lon0, 0.0)]},
           "geoFence": {"version": 2, "polygons": [], "circles": []}, "rallyPoints": {"version": 2, "points": []}}
    path = tmp_path / "survey.plan"
    path.write_text(json.dumps(doc))
    mission, _, _ = read_plan(path)
    assert [m.command for m in mission] == [22, 16, 16, 16, 16, 21]
    assert [m.seq for m in mission] == list(range(6))
    assert mission[3].x == round((lat0 + 2e-5) * 1e7) and mission[2].y == round((lon0 + 2e-5) * 1e7)
    doc["mission"]["items"][1] = {"type": "ComplexItem", "complexItemType": "StructureScan", "Items": []}
    path.write_text(json.dumps(doc))
    with pytest.raises(PlanError, match=r"item 1 is a 'StructureScan' ComplexItem without saved items"):
        read_plan(path)
