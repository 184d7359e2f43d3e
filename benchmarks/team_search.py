"""Team benchmark (issue 18): time to "source found" with 1 vs N vehicles, in-process.

One vehicle flies ``launch.offline.fly_offline`` (the single-vehicle product, unchanged); N vehicles fly
``launch.offline_team.fly_team_offline`` (the joint brain, one estimate from all vehicles' frames, each
vehicle's odometry drift its own). Same scene, same seeds, same search settings. Per team size:

* ``median_found_s``: median simulated seconds from take-off to the "source found" decision; a flight that
  ended otherwise (dwell budget, no frontier) counts as never found (+inf), so the median is honest;
* ``found``: share of flights that ended "source found" (``Outcome.found``: ``found`` or ``drift_limited``);
* ``median_error_m``, ``p90_error_m``: x-y distance of the final estimate from the truth;
* ``coverage_95``: share of flights whose reported 95 % ellipse holds the truth (``launch.campaign.coverage``;
  ``covered`` of ``judged`` flights);
* ``median_dwells``: dwell points of the whole team;
* ``min_separation_m``: the smallest true x-y distance between two vehicles over all flights (teams only).

    python benchmarks/team_search.py [--seeds 20] [--first-seed 0] [--vehicles 1 2] [--scene default]
        [--workers 2] [--json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np


def fly(spec: tuple[str, int, int]) -> dict:
    """One flight: (scene, vehicles, seed) -> its row."""
    from detector_fw_sim.scene import load_scene
    from launch.campaign import coverage

    scene_name, n, seed = spec
    scene = load_scene(scene_name)
    if n == 1:
        from launch.offline import fly_offline

        r = fly_offline(scene, seed=seed)
        reason, outcome = r.decisions[-1].reason, r.decisions[-1].outcome
        min_sep, dwells = math.inf, len(r.dwell_rates)
    else:
        from launch.offline_team import fly_team_offline

        r = fly_team_offline(scene, n, seed=seed)
        reason = r.brain.final.reason if r.brain.final else "stopped"
        outcome = r.brain.final.outcome if r.brain.final else None
        min_sep = r.min_separation_m
        dwells = len(r.brain.history)
    est = r.estimate
    src = r.dataset.truth.sources[0]
    _, covered = coverage(est, (src.x, src.y))
    return {"scene": scene_name, "vehicles": n, "seed": seed, "error_m": r.error_m,
            "mission_time_s": r.mission_time_s, "found": outcome is not None and outcome.found, "covered_95": covered,
            "sigma_m": est.sigma_m if est else math.inf, "min_separation_m": min_sep, "reason": reason,
            "dwell_points": dwells}


def summarize(rows: list[dict], n: int) -> dict:
    rs = [r for r in rows if r["vehicles"] == n]
    t = np.array([r["mission_time_s"] if r["found"] else math.inf for r in rs])
    err = np.array([r["error_m"] for r in rs])
    cov = [r["covered_95"] for r in rs if r["covered_95"] is not None]
    return {"vehicles": n, "runs": len(rs), "median_found_s": float(np.median(t)),
            "found": float(np.mean([r["found"] for r in rs])),
            "median_error_m": float(np.median(err)), "p90_error_m": float(np.percentile(err, 90)),
            "coverage_95": float(np.mean(cov)) if cov else math.nan, "covered": int(sum(cov)), "judged": len(cov),
            "median_dwells": float(np.median([r["dwell_points"] for r in rs])),
            "min_separation_m": float(min(r["min_separation_m"] for r in rs))}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", type=int, default=20)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--vehicles", type=int, nargs="+", default=[1, 2])
    p.add_argument("--scene", default="default")
    p.add_argument("--workers", type=int, default=1, help="processes (default 1)")
    p.add_argument("--json", action="store_true", help="one JSON object per team size instead of the table")
    args = p.parse_args(argv)
    specs = [(args.scene, n, s) for n in args.vehicles for s in range(args.first_seed, args.first_seed + args.seeds)]
    if args.workers > 1:
        with ProcessPoolExecutor(args.workers) as ex:
            rows = list(ex.map(fly, specs))
    else:
        rows = [fly(s) for s in specs]
    out = [summarize(rows, n) for n in args.vehicles]
    base = out[0]["median_found_s"]
    if args.json:
        for o in out:
            print(json.dumps(o))
        return 0
    print("| vehicles | runs | median time to source found (s) | x one vehicle | found | median dwells (team) "
          "| median error (m) | p90 error (m) | 95 % coverage | min true separation (m) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for o in out:
        print(f"| {o['vehicles']} | {o['runs']} | {o['median_found_s']:.1f} | {o['median_found_s'] / base:.2f} "
              f"| {o['found']:.2f} | {o['median_dwells']:.0f} | {o['median_error_m']:.3f} | {o['p90_error_m']:.3f} "
              f"| {o['coverage_95']:.2f} ({o['covered']}/{o['judged']}) | {o['min_separation_m']:.2f} |", flush=True)
    for r in rows:
        if not r["found"]:
            print(f"not found: {r['vehicles']} vehicles seed {r['seed']}: {r['reason']}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
