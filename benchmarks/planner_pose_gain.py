"""Side by side: the next-best planner scoring with paper 003 eq. 6 against eq. 6 under pose covariance
(``NextBestConfig.gain_kind`` "eq6" vs "eq6_pose", issue 13 item 3), whole active searches flown with the
in-process driver (``launch.offline.fly_offline``) on the same seeds: same scene, detector noise and
odometry drift draws; only the planner's gain differs (OMPL's trees are not seedable per call, so the trees
differ run to run anyway).

Per gain: median and p90 position error (x-y, m), coverage of the reported 95 % ellipse (fraction of
flights whose 2-D chi-square(0.95) ellipse of the in-flight covariance holds the truth), median dwell points
after exploration, median metres flown (whole flight, and during the search phase, which is the part the
gain decides), the mean paired difference of metres flown with its standard error, and the median 1-sigma
and drift (odometry standard deviation at the end of the flight).

    python benchmarks/planner_pose_gain.py [--seeds 40] [--scene default] [--stop-sigma 0.1] [--jobs 1] [--json]
    python benchmarks/planner_pose_gain.py --same-tree [--seeds 30]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from detector_fw_sim.scene import load_scene
from launch.offline import fly_offline
from mission.search import Phase, SearchConfig
from planner.next_best import NextBestConfig

#: the two eq. 6 gains this benchmark compares (the information planner is measured by mission_search.py)
EQ6_GAINS = ("eq6", "eq6_pose")

CHI2_2D_95 = 5.991464547107979  # chi-square quantile, 2 dof, 0.95


def fly(scene_name: str, gain_kind: str, seed: int, stop_sigma_m: float = SearchConfig.stop_sigma_m) -> dict:
    """One search; the numbers the table needs."""
    scene = load_scene(scene_name)
    t0 = time.perf_counter()
    config = SearchConfig(stop_sigma_m=stop_sigma_m, next_best=NextBestConfig(gain_kind=gain_kind))
    r = fly_offline(scene, config, seed=seed)
    wall = time.perf_counter() - t0
    est, truth = r.estimate, r.dataset.truth.sources[0]
    covered, sigma = False, math.inf
    if est is not None:
        d = np.array([est.x - truth.x, est.y - truth.y])
        cov = est.covariance[:2, :2]
        try:
            covered = bool(d @ np.linalg.solve(cov, d) <= CHI2_2D_95)
        except np.linalg.LinAlgError:
            covered = False
        sigma = float(est.sigma_m)
    flown = float(np.linalg.norm(np.diff(r.true_path[:, :3], axis=0), axis=1).sum())
    search_m = sum(d.plan.path_length() for d in r.decisions if d.phase is Phase.SEARCH and d.plan is not None)
    var = r.dataset.frames.pose_variances[-1]
    return {"seed": seed, "gain": gain_kind, "error_m": r.error_m, "covered": covered, "sigma_m": sigma,
            "search_dwells": r.brain.search_dwells, "flown_m": flown, "search_m": float(search_m),
            "drift_m": float(math.sqrt(var[0] + var[1])), "wall_s": wall}


def same_tree_choices(scene_name: str, seed: int, flown_gain: str = "eq6") -> list[dict]:
    """Fly one search with ``flown_gain`` and, at every next-best decision, score the *same* tree with both
    gains: the chosen node's path length (m) and tree/eq. 6 numbers under each. This removes the trees'
    randomness from the comparison (a per-decision paired test of what the gain changes)."""
    import mission.search as ms
    from planner.dwell_tree import grow_tree
    from planner.next_best import score_nodes

    out: list[dict] = []
    plan = ms.plan_next_dwell

    def both(current, belief, history, occ, config, rng=None, **kw):
        tree = grow_tree(current, occ, config.tree)
        pos = tree.states[:, :3]
        straight = occ.segments_valid(np.broadcast_to(pos[0], pos.shape), pos)
        length = np.where(straight, np.linalg.norm(pos - pos[0], axis=1), tree.path_lengths())
        row = {"seed": seed, "sigma_m": float(np.sqrt(np.linalg.eigvalsh(belief.covariance[:2, :2]).max()))}
        for g in EQ6_GAINS:
            s = score_nodes(pos, belief, history, occ, dataclasses.replace(config, gain_kind=g), path_length=length)
            row[f"L_{g}"] = float(length[s.best]) if s.best >= 0 else math.nan
        out.append(row)
        return plan(current, belief, history, occ, config, rng=rng, tree=tree, **kw)

    ms.plan_next_dwell = both
    try:
        fly_offline(load_scene(scene_name), SearchConfig(next_best=NextBestConfig(gain_kind=flown_gain)), seed=seed)
    finally:
        ms.plan_next_dwell = plan
    return out


def summarise(rows: list[dict]) -> dict:
    a = {k: np.array([r[k] for r in rows], dtype=float) for k in rows[0] if k != "gain"}
    return {
        "gain": rows[0]["gain"], "runs": len(rows), "median_error_m": float(np.median(a["error_m"])),
        "p90_error_m": float(np.percentile(a["error_m"], 90)), "coverage_95": float(a["covered"].mean()),
        "median_search_dwells": float(np.median(a["search_dwells"])), "median_flown_m": float(np.median(a["flown_m"])),
        "median_search_m": float(np.median(a["search_m"])), "median_sigma_m": float(np.median(a["sigma_m"])),
        "median_drift_m": float(np.median(a["drift_m"])), "median_wall_s": float(np.median(a["wall_s"])),
    }


def paired(base: list[dict], new: list[dict], key: str) -> tuple[float, float]:
    """Mean and standard error of new - base over the shared seeds."""
    b = {r["seed"]: r[key] for r in base}
    d = np.array([r[key] - b[r["seed"]] for r in new if r["seed"] in b], dtype=float)
    d = d[np.isfinite(d)]
    return float(d.mean()), float(d.std(ddof=1) / math.sqrt(len(d))) if len(d) > 1 else math.nan


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", type=int, default=40)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--scene", default="default")
    p.add_argument("--gains", nargs="+", default=list(EQ6_GAINS), choices=EQ6_GAINS)
    p.add_argument("--stop-sigma", type=float, default=SearchConfig.stop_sigma_m,
                   help="m: the search's stop rule (smaller: longer searches, where the gain decides more metres)")
    p.add_argument("--jobs", type=int, default=1, help="worker processes (the searches are independent)")
    p.add_argument("--json", action="store_true", help="also print one JSON object per gain and the raw rows")
    p.add_argument("--same-tree", action="store_true",
                   help="instead: per decision, the path length each gain chooses on the same tree (eq6 flights)")
    args = p.parse_args(argv)
    if args.same_tree:
        rows = [r for s in range(args.first_seed, args.first_seed + args.seeds)
                for r in same_tree_choices(args.scene, s)]
        d = np.array([r["L_eq6_pose"] - r["L_eq6"] for r in rows])
        med = {g: float(np.median([r[f"L_{g}"] for r in rows])) for g in EQ6_GAINS}
        print(f"{len(rows)} decisions: eq6_pose chose another node in {int((d != 0).sum())}; path length "
              f"eq6_pose - eq6 mean {d.mean():+.3f} m (s.e. {d.std(ddof=1) / math.sqrt(len(d)):.3f}), "
              f"median L eq6 {med['eq6']:.2f} m, eq6_pose {med['eq6_pose']:.2f} m")
        if args.json:
            for r in rows:
                print(json.dumps(r))
        return 0
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    # interleaved, so the machine load hits both gains alike
    tasks = [(args.scene, g, s, args.stop_sigma) for s in seeds for g in args.gains]
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as ex:
            rows = list(ex.map(fly, *zip(*tasks, strict=True)))
    else:
        rows = [fly(*t) for t in tasks]
    by_gain = {g: [r for r in rows if r["gain"] == g] for g in args.gains}
    print(f"scene {args.scene}, seeds {seeds.start}-{seeds.stop - 1}, stop at 1-sigma < {args.stop_sigma} m")
    print("| gain | runs | median error (m) | p90 error (m) | 95 % ellipse coverage | median dwells after "
          "exploration | median metres flown (search phase) | median 1-sigma (m) | median drift at end (m) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for g, rs in by_gain.items():
        s = summarise(rs)
        print(f"| {g} | {s['runs']} | {s['median_error_m']:.3f} | {s['p90_error_m']:.3f} | {s['coverage_95']:.2f} "
              f"| {s['median_search_dwells']:.0f} | {s['median_flown_m']:.1f} ({s['median_search_m']:.1f}) "
              f"| {s['median_sigma_m']:.3f} | {s['median_drift_m']:.3f} |")
        if args.json:
            print(json.dumps({"scene": args.scene, **s}))
    if len(args.gains) == 2:
        base, new = by_gain[args.gains[0]], by_gain[args.gains[1]]
        for key in ("flown_m", "search_m", "error_m", "search_dwells"):
            m, se = paired(base, new, key)
            print(f"paired {args.gains[1]} - {args.gains[0]} {key}: {m:+.3f} +- {se:.3f} (mean +- s.e.)")
    if args.json:
        for r in rows:
            print(json.dumps(r))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
