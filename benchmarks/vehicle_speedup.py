"""How much faster than real time the mock vehicle flies a 10-minute mission.

Starts ``radseek vehicle`` (no zenoh) at each requested ``--speedup``, uploads a mission of about
600 sim seconds (takeoff, 10 dwell points of 50 s, 20 m legs, land) with a pymavlink ground station,
flies it to the landing, and reports sim time / wall time. Sim time comes from the vehicle's own
``time_boot_ms`` stamps.

    .venv/bin/python benchmarks/vehicle_speedup.py --speedups 10,50,200,1000
"""

from __future__ import annotations

import argparse
import math
import time

from pymavlink.dialects.v20 import common as M

from mission.vehicle.frames import Home, enu_to_geodetic
from mission.vehicle.harness import Gcs, VehicleProcess, free_udp_port, item


def mission(home: Home) -> list:
    pts = [(20.0 * math.cos(k * 0.9), 20.0 * math.sin(k * 0.9), 3.0) for k in range(10)]
    items = [item(0, M.MAV_CMD_NAV_TAKEOFF, home.lat_deg, home.lon_deg, 3.0)]
    for p in pts:
        lat, lon, _ = enu_to_geodetic(home, p)
        items.append(item(len(items), M.MAV_CMD_NAV_WAYPOINT, lat, lon, p[2], 50.0))
    items.append(item(len(items), M.MAV_CMD_NAV_RETURN_TO_LAUNCH, frame=M.MAV_FRAME_MISSION))
    return items


def fly(speedup: float) -> tuple[float, float]:
    api = free_udp_port()
    with VehicleProcess(api, free_udp_port(), ["--speedup", str(speedup)]), Gcs(api, keepalive=True) as gcs:
        gcs.wait_vehicle()
        assert gcs.upload(mission(Home())) == M.MAV_MISSION_ACCEPTED
        assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
        t_sim0 = gcs.recv("LOCAL_POSITION_NED").time_boot_ms / 1000
        wall0 = time.monotonic()
        assert gcs.command(M.MAV_CMD_DO_SET_MODE, 1, 4, 4) == M.MAV_RESULT_ACCEPTED
        gcs.recv("MISSION_CURRENT", lambda m: m.mission_state == 5, timeout=3600)  # COMPLETE
        wall = time.monotonic() - wall0
        t_sim = gcs.recv("LOCAL_POSITION_NED").time_boot_ms / 1000 - t_sim0
    return t_sim, wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--speedups", default="50,200,1000", help="comma-separated requested speed-ups")
    args = ap.parse_args()
    print(f"{'requested':>10} {'sim s':>8} {'wall s':>8} {'achieved':>9}")
    for s in (float(v) for v in args.speedups.split(",")):
        t_sim, wall = fly(s)
        print(f"{s:10.0f} {t_sim:8.1f} {wall:8.2f} {t_sim / wall:9.1f}", flush=True)


if __name__ == "__main__":
    main()
