"""How much faster than real time the mock vehicle flies a 10-minute mission.

Starts ``radseek vehicle`` (no zenoh) at each requested ``--speedup``, uploads a mission of about
600 sim seconds (takeoff, 10 dwell points of 50 s, 20 m legs, land) with a pymavlink ground station,
flies it to the landing, and reports sim time / wall time. Sim time comes from the vehicle's own
clock, read with a TIMESYNC exchange (its reply carries sim time).

    .venv/bin/python benchmarks/vehicle_speedup.py --speedups 10,50,200,1000
"""

from __future__ import annotations

import argparse
import contextlib
import math
import socket
import subprocess
import sys
import time

from pymavlink.dialects.v20 import common as M

from radseek.coordinates import Home, enu_to_geodetic
from vehicle_sim.harness import Gcs, VehicleProcess, free_udp_port, item


def mission(home: Home) -> list:
    pts = [(20.0 * math.cos(k * 0.9), 20.0 * math.sin(k * 0.9), 3.0) for k in range(10)]
    items = [item(0, M.MAV_CMD_NAV_TAKEOFF, home.lat_deg, home.lon_deg, 3.0)]
    for p in pts:
        lat, lon, _ = enu_to_geodetic(home, p)
        items.append(item(len(items), M.MAV_CMD_NAV_WAYPOINT, lat, lon, p[2], 50.0))
    items.append(item(len(items), M.MAV_CMD_NAV_RETURN_TO_LAUNCH, frame=M.MAV_FRAME_MISSION))
    return items


@contextlib.contextmanager
def zenoh_router():
    """A router on a free port and a subscriber counting sim/truth_pose samples: yields (endpoint, counter)."""
    from radseek import topics
    from radseek.zenoh_session import open_session

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    router = subprocess.Popen([sys.executable, "-m", "radseek_cli", "router", "--listen", endpoint],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        router.stdout.readline()
        count = [0]
        with open_session(connect=endpoint) as session:
            sub = session.declare_subscriber(topics.key(topics.SIM_TRUTH_POSE),
                                             lambda _s: count.__setitem__(0, count[0] + 1))
            yield endpoint, count
            sub.undeclare()
    finally:
        router.terminate()
        router.wait(10)


def sim_now(gcs: Gcs) -> float:
    """The vehicle's sim time (s), from its answer to a TIMESYNC request."""
    ts1 = time.monotonic_ns()
    gcs.send(M.MAVLink_timesync_message(0, ts1))
    return gcs.recv("TIMESYNC", lambda m: m.ts1 == ts1 and m.tc1 != 0).tc1 / 1e9


def fly(speedup: float, endpoint: str | None = None) -> tuple[float, float]:
    api = free_udp_port()
    extra = ["--connect", endpoint] if endpoint else []
    with (VehicleProcess(api, free_udp_port(), ["--speedup", str(speedup), *extra], zenoh=endpoint is not None),
          Gcs(api, keepalive=True) as gcs):
        gcs.wait_vehicle()
        assert gcs.upload(mission(Home())) == M.MAV_MISSION_ACCEPTED
        assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
        t_sim0 = sim_now(gcs)
        wall0 = time.monotonic()
        assert gcs.command(M.MAV_CMD_DO_SET_MODE, 1, 4, 4) == M.MAV_RESULT_ACCEPTED
        gcs.recv("MISSION_CURRENT", lambda m: m.mission_state == 5, timeout=3600)  # COMPLETE
        wall = time.monotonic() - wall0
        t_sim = sim_now(gcs) - t_sim0
    return t_sim, wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--speedups", default="50,200,1000", help="comma-separated requested speed-ups")
    ap.add_argument("--zenoh", action="store_true", help="publish on zenoh through a router, as in the stack")
    args = ap.parse_args()
    print(f"{'requested':>10} {'sim s':>8} {'wall s':>8} {'achieved':>9}" + (" truth-poses" if args.zenoh else ""))
    for s in (float(v) for v in args.speedups.split(",")):
        if args.zenoh:
            with zenoh_router() as (endpoint, count):
                t_sim, wall = fly(s, endpoint)
                time.sleep(0.2)
            tail = f" {count[0]:11d}"
        else:
            t_sim, wall = fly(s)
            tail = ""
        print(f"{s:10.0f} {t_sim:8.1f} {wall:8.2f} {t_sim / wall:9.1f}{tail}", flush=True)


if __name__ == "__main__":
    main()
