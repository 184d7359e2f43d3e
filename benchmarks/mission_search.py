"""Whole-search benchmark (issue 6 targets): the active search of paper 003 against the 9-point lattice and
the lawnmower, over seeded flights of the in-process driver (launch.offline: the same brain, estimator and
planner as `radseek run`, the emulator for counts, odometry drift as on the mock vehicle).

Reports per scene and strategy: median and 90th-percentile position error, median dwell points (and, for
the active search, dwell points after exploration), median mission time (simulated seconds from the first
dwell flight to the stop decision) and wall time per search.

    python benchmarks/mission_search.py [--seeds 20] [--quick] [--scenes default lattice-wall]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from detector_fw_sim.scene import load_scene
from launch.offline import fly_offline
from mission.search import STRATEGIES, SearchConfig


def run(scene_name: str, strategy: str, seeds: range) -> dict:
    scene = load_scene(scene_name)
    rows = []
    for seed in seeds:
        t0 = time.perf_counter()
        r = fly_offline(scene, SearchConfig(strategy=strategy), seed=seed)
        rows.append((r.error_m, len(r.dwell_rates), r.brain.search_dwells, r.mission_time_s,
                     time.perf_counter() - t0))
    a = np.array(rows)
    return {
        "scene": scene_name, "strategy": strategy, "runs": len(a),
        "median_error_m": float(np.median(a[:, 0])), "p90_error_m": float(np.percentile(a[:, 0], 90)),
        "median_dwells": float(np.median(a[:, 1])), "median_search_dwells": float(np.median(a[:, 2])),
        "median_mission_s": float(np.median(a[:, 3])), "median_wall_s": float(np.median(a[:, 4])),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", type=int, default=20)
    p.add_argument("--quick", action="store_true", help="5 seeds, default scene only")
    p.add_argument("--scenes", nargs="+", default=["default", "lattice-wall"])
    p.add_argument("--strategies", nargs="+", default=list(STRATEGIES))
    args = p.parse_args(argv)
    seeds = range(5) if args.quick else range(args.seeds)
    scenes = ["default"] if args.quick else args.scenes
    print("| scene | strategy | runs | median error (m) | p90 error (m) | median dwells (after exploration) "
          "| median mission time (s) | wall per search (s) |")
    print("|---|---|---|---|---|---|---|---|")
    for scene in scenes:
        for strategy in args.strategies:
            r = run(scene, strategy, seeds)
            after = f" ({r['median_search_dwells']:.0f})" if strategy == "active" else ""
            print(f"| {scene} | {strategy} | {r['runs']} | {r['median_error_m']:.3f} | {r['p90_error_m']:.3f} "
                  f"| {r['median_dwells']:.0f}{after} | {r['median_mission_s']:.0f} | {r['median_wall_s']:.1f} |",
                  flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
