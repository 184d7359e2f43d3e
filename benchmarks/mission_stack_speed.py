"""Speed of the real stack (issue 6 target: a 10-minute mission simulates in <= 20 s wall): runs
`radseek run` (router, vehicle, detector, mission as processes over zenoh and MAVLink) with a long
fixed-pattern mission at a high speed-up and reports simulated flight time against wall time.

    python benchmarks/mission_stack_speed.py [--speedup 40] [--strategy lawnmower] [--quick]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--speedup", type=float, default=40.0)
    p.add_argument("--strategy", default="lawnmower")
    p.add_argument("--quick", action="store_true", help="the lattice instead of the lawnmower")
    args = p.parse_args(argv)
    strategy = "lattice" if args.quick else args.strategy
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        t0 = time.monotonic()
        proc = subprocess.run(
            [sys.executable, "-m", "radseek_cli", "run", "--out", str(out), "--quiet", "--speedup", str(args.speedup),
             "--strategy", strategy, "--max-dwells", "40", "--zenoh-port", "27647", "--mavlink-port", "24740",
             "--gcs-port", "24750", "--vehicle-local-ports", "24780,28770"],
            capture_output=True, text=True)
        wall = time.monotonic() - t0
        if proc.returncode != 0:
            print(proc.stderr[-2000:])
            return 1
        s = json.loads((out / "summary.json").read_text())
        flight, mission_wall = s["flight_time_s"], s.get("wall_time_s") or wall
        print(f"strategy {strategy}, speed-up {args.speedup:g}: {s['dwell_points']} dwell points, "
              f"{flight:.0f} s simulated flight in {mission_wall:.1f} s wall for the whole stack "
              f"(start-up included), {wall:.1f} s with the report")
        print(f"effective speed-up {flight / mission_wall:.1f}x -> a 10-minute mission: "
              f"{600 / (flight / mission_wall):.1f} s wall; error {s['error_m']:.3f} m")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
