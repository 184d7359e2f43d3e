"""QGroundControl .plan export, and the vehicle's determinism: same seed and commands, same flight."""

import json
import math

import numpy as np
import pytest

from mission.client.mission_upload import DwellPoint, build_items
from mission.qgc_plan import write_plan
from radseek.coordinates import Home
from vehicle_sim.harness import thread_config
from vehicle_sim.vehicle import Vehicle


def test_plan_file_is_qgc_mission_v2(tmp_path):
    home = Home()
    items = build_items([DwellPoint(5, 0, 3, yaw=None, max_dwell_s=30), DwellPoint(5, 5, 4, yaw=0.0)], home,
                        takeoff_alt=3.0, finish="rtl")
    plan = json.loads(write_plan(tmp_path / "p.plan", items, home).read_text())
    assert plan["fileType"] == "Plan" and plan["mission"]["version"] == 2
    assert plan["mission"]["plannedHomePosition"] == [home.lat_deg, home.lon_deg, home.alt_m]
    it = plan["mission"]["items"]
    assert [i["command"] for i in it] == [22, 16, 16, 20]
    assert it[1]["params"][0] == 30 and it[1]["params"][3] is None  # NaN yaw written as null
    assert it[2]["params"][3] == 90.0 and it[2]["Altitude"] == 4.0 and it[2]["AltitudeMode"] == 1
    assert it[1]["frame"] == 3 and it[3]["frame"] == 2 and "Altitude" not in it[3]
    assert it[1]["params"][4] == items[1].x / 1e7


def _fly(seed: int) -> tuple[np.ndarray, np.ndarray]:
    v = Vehicle(thread_config(0, 0, seed=seed))
    try:
        v.nav.arm()
        v.nav.takeoff(3.0)
        for _ in range(100):
            v.step(0.05, link_age=None)
        v.nav.goto(np.array([15.0, 10.0, 3.0]), math.pi)
        for _ in range(400):
            v.step(0.05, link_age=None)
        truth, _ = v.truth()
        return truth, v.odo.var.copy()
    finally:
        v.link.close()


@pytest.mark.io
def test_same_seed_same_flight_other_seed_other_drift():
    a, var_a = _fly(7)
    b, var_b = _fly(7)
    c, _ = _fly(8)
    assert np.array_equal(a, b) and np.array_equal(var_a, var_b)
    assert not np.allclose(a, c)
