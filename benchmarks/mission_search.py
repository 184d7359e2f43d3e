"""Whole-search benchmark (issue 6 targets): the active search of paper 003 against the 9-point lattice and
the lawnmower, over seeded flights of the in-process driver (launch.offline: the same brain, estimator and
planner as `radseek run`, the emulator for counts, odometry drift as on the mock vehicle).

Reports per scene and strategy: median and 90th-percentile position error, median dwell points (and, for
the active search, dwell points after exploration), median mission time (simulated seconds from the first
dwell flight to the stop decision), the share of flights whose 95 % ellipse covers the truth, and wall time
per search, and the median drift-aware bound (``bound_m`` of the final in-flight estimate: the hybrid
Cramér-Rao bound with the random-walk pose prior, rms horizontal) that the median error is to be held against.
``--json`` prints one JSON object per (scene, strategy) instead of the table: ``scene, strategy, runs,
median_error_m, p90_error_m, coverage_95`` (share of flights whose reported 95 % ellipse holds the truth),
``median_bound_m, median_dwells, median_search_dwells, median_mission_s, median_wall_s``.

The seeds run as a campaign (``radseek campaign``, launch.campaign: one Ray task per flight, all CPUs unless
--workers; --address for an existing Ray cluster); --out keeps its Parquet rows and a rerun resumes them.

    python benchmarks/mission_search.py [--seeds 20] [--quick] [--scenes default lattice-wall outdoor] [--workers 2]
        [--json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile

import numpy as np

from launch.campaign import Sweep, run_campaign
from mission.search import ACTIVE, STRATEGIES, Outcome

#: the campaign rows' ``outcome`` values of a found source
FOUND = {o.value for o in Outcome if o.found}


def summarize(rows: list[dict], scene_name: str, strategy: str) -> dict:
    rows = [r for r in rows if r["scene"] == scene_name and r["strategy"] == strategy and r["status"] == "ok"]
    a = np.array([(r["error_m"], r["dwell_points"], r["search_dwells"], r["mission_time_s"], r["wall_s"])
                  for r in rows], dtype=float).reshape(-1, 5)
    cov = [r["covered_95"] for r in rows if r["covered_95"] is not None]
    bounds = [float(r["est.bound_m"]) for r in rows if r.get("est.bound_m") is not None]
    bounds = [b for b in bounds if math.isfinite(b)]
    return {
        "scene": scene_name, "strategy": strategy, "runs": len(a),
        "median_error_m": float(np.median(a[:, 0])), "p90_error_m": float(np.percentile(a[:, 0], 90)),
        "median_dwells": float(np.median(a[:, 1])), "median_search_dwells": float(np.median(a[:, 2])),
        "median_mission_s": float(np.median(a[:, 3])), "median_wall_s": float(np.median(a[:, 4])),
        "coverage_95": float(np.mean(cov)) if cov else float("nan"),
        "median_bound_m": float(np.median(bounds)) if bounds else float("nan"),
        "median_cpu_s": float(np.median([r["cpu_s"] for r in rows])) if rows else float("nan"),
        "found": float(np.mean([r.get("outcome") in FOUND for r in rows])) if rows
        else float("nan"),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", type=int, default=20)
    p.add_argument("--quick", action="store_true", help="5 seeds, default scene only")
    p.add_argument("--scenes", nargs="+", default=["default", "lattice-wall", "outdoor"])
    p.add_argument("--strategies", nargs="+", default=list(STRATEGIES))
    p.add_argument("--workers", type=int, help="CPUs of the embedded Ray (default: all)")
    p.add_argument("--address", help="an existing Ray cluster (HOST:PORT)")
    p.add_argument("--out", help="campaign folder to keep (and resume); default a temporary one")
    p.add_argument("--json", action="store_true", help="one JSON object per (scene, strategy) instead of the table")
    p.add_argument("--niceness", type=int, default=0,
                   help="nice level of the embedded Ray workers (default 0: a benchmark measures speed; Ray's own "
                        "default of 15 lets every other process on the machine go first)")
    args = p.parse_args(argv)
    seeds = range(5) if args.quick else range(args.seeds)
    scenes = ["default"] if args.quick else args.scenes
    sweep = Sweep(scenes=scenes, strategies=args.strategies, seeds=list(seeds))
    with tempfile.TemporaryDirectory(prefix="mission-search-") as tmp:
        res = run_campaign(sweep, args.out or tmp, workers=args.workers, address=args.address, plots=False,
                           niceness=args.niceness)
    keys = ("scene", "strategy", "runs", "median_error_m", "p90_error_m", "coverage_95", "median_bound_m",
            "median_dwells", "median_search_dwells", "median_mission_s", "median_wall_s", "median_cpu_s", "found")
    if not args.json:
        print("| scene | strategy | runs | median error (m) | p90 error (m) | median bound (m) "
              "| median dwells (after exploration) | median mission time (s) | 95 % ellipse coverage "
              "| wall (CPU) per search (s) | found |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
    for scene in scenes:
        for strategy in args.strategies:
            r = summarize(res.rows, scene, strategy)
            if args.json:
                print(json.dumps({k: r[k] for k in keys}), flush=True)
                continue
            after = f" ({r['median_search_dwells']:.0f})" if strategy in ACTIVE else ""
            print(f"| {scene} | {strategy} | {r['runs']} | {r['median_error_m']:.3f} | {r['p90_error_m']:.3f} "
                  f"| {r['median_bound_m']:.3f} | {r['median_dwells']:.0f}{after} | {r['median_mission_s']:.0f} "
                  f"| {r['coverage_95']:.2f} | {r['median_wall_s']:.1f} ({r['median_cpu_s']:.1f}) | {r['found']:.2f} |",
                  flush=True)
    failed = [r for r in res.rows if r["status"] != "ok"]
    for r in failed:
        print(f"failed: {r['scene']} {r['strategy']} seed {r['seed']}: {r['error']}",
              file=sys.stderr if args.json else sys.stdout)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
