"""Planning time per call of the next-best-dwell-point planner (target: <= 0.2 s for 500 nodes, one core).

Run: ``.venv/bin/python benchmarks/planner_timing.py [--repeats 20] [--nodes 100,200,500,1000]``
(``taskset -c 0`` pins it to one core). Prints, per scene and tree size, the median and 90th percentile
of the tree growth time (OMPL RRT with the Python validity callbacks) and of the whole call (tree +
eq. 6 scoring + shortcut + yaw choice), in wall-clock time, and the median CPU time of the call
(``time.process_time``: what one core spends, less sensitive to other jobs on a shared machine).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from planner.belief import DwellHistory, SourceBelief
from planner.dwell_tree import TreeConfig, seed_ompl
from planner.next_best import NextBestConfig, plan_next_dwell
from planner.occupancy import OccupancyMap
from radseek.dataset import Wall


def scenes() -> dict[str, OccupancyMap]:
    lo, hi = np.array([0.0, 0.0, 0.5]), np.array([10.0, 8.0, 2.5])
    door = (Wall((5.0, 0.0), (5.0, 3.4), 0.2, 3.0), Wall((5.0, 4.6), (5.0, 8.0), 0.2, 3.0),
            Wall((1.5, 5.0), (3.0, 6.5), 0.3, 2.0))
    rooms = door + tuple(Wall((x, 0.0), (x, 5.0), 0.2, 3.0) for x in (2.0, 8.0)) + (
        Wall((0.0, 6.0), (4.0, 6.0), 0.2, 3.0), Wall((6.0, 2.0), (10.0, 2.0), 0.2, 3.0))
    return {
        "empty 10x8 m": OccupancyMap(lo, hi, (), 0.3),
        "wall with door (3 walls)": OccupancyMap(lo, hi, door, 0.3),
        "rooms (7 walls)": OccupancyMap(lo, hi, rooms, 0.3),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--nodes", default="100,200,500,1000")
    args = ap.parse_args()
    seed_ompl(7)
    rng = np.random.default_rng(7)
    belief = SourceBelief(np.array([7.5, 4.0, 0.0]), np.eye(3) * 0.09, 2000.0, 30.0)
    history = DwellHistory(np.array([[1.0, 1.0, 1.5], [3.0, 1.0, 1.5], [4.0, 4.0, 1.5]]), np.array([60, 90, 200.0]))
    start = np.array([1.0, 1.0, 1.5, 0.0])
    print(f"{'scene':<26} {'nodes':>5} {'tree med':>9} {'tree p90':>9} {'call med':>9} {'call p90':>9} "
          f"{'cpu med':>9}  (s)")
    for name, occ in scenes().items():
        for n in (int(v) for v in args.nodes.split(",")):
            cfg = NextBestConfig(tree=TreeConfig(n_min=n, n_max=n, time_budget=30.0, time_limit=30.0))
            tree_t, call_t, cpu_t = [], [], []
            for _ in range(args.repeats):
                t0, c0 = time.perf_counter(), time.process_time()
                plan = plan_next_dwell(start, belief, history, occ, cfg, rng=rng)
                call_t.append(time.perf_counter() - t0)
                cpu_t.append(time.process_time() - c0)
                tree_t.append(plan.info["tree_time_s"])
                assert plan.info["nodes"] == n, plan.info
            print(f"{name:<26} {n:>5} {np.median(tree_t):9.4f} {np.percentile(tree_t, 90):9.4f} "
                  f"{np.median(call_t):9.4f} {np.percentile(call_t, 90):9.4f} {np.median(cpu_t):9.4f}")


if __name__ == "__main__":
    main()
