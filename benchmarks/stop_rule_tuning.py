"""Tune the information search's drift-limited stop (``SearchConfig.bound_fall_m_s``) on tuning seeds: fly each
seed once with that stop off (``bound_fall_m_s=0``: the flight goes on to the 1-sigma target or the budget) and
keep, at every stop decision, the mission time, the in-flight estimate's error, whether the rest of the rule held
(searched, 1-sigma below 1 m, stable, fitting) and the planner's expected fall of the flown frames' bound per
second of the next leg, and whether main's rule (the 1-sigma stopped falling at the landmark-free drift floor)
held. The rule with threshold X stops each flight at the first decision whose fall is below X
(the planner never looks at the stop rule, so the flight up to there is the same), which gives median error
and time for every X, and main's stop paired with it, from one set of flights.

    python benchmarks/stop_rule_tuning.py --scenes default lattice-wall --seed0 1000 --seeds 30 \\
        --out runs/stop-tuning.jsonl
    python benchmarks/stop_rule_tuning.py --read runs/stop-tuning.jsonl --allowance 78
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

#: m/s, the thresholds the table compares
THRESHOLDS = (0.0, 1e-4, 2e-4, 3e-4, 5e-4, 7e-4, 1e-3, 1.5e-3, 2e-3, 3e-3)


def fly(scene_name: str, seed: int) -> dict:
    """One info flight with the bound-fall stop off: its stop decisions along the flight."""
    from detector_fw_sim.scene import load_scene
    from launch.offline import fly_offline
    from mission.search import LOCALISED_M, SearchBrain, SearchConfig

    seen: list[dict] = []
    original = SearchBrain.stop_rule

    def recording(self, belief, sigma, bound_fall_m_s=None):
        out = original(self, belief, sigma, bound_fall_m_s)
        if bound_fall_m_s is not None:
            searched = belief is not None and self.search_dwells >= self.config.min_search_dwells
            seen.append({"dwells": len(self.history), "fall_m_s": bound_fall_m_s,
                         "bound_m": self.bound_falls[-1][1] if self.bound_falls else math.nan,
                         "eligible": bool(searched and sigma < LOCALISED_M and self._stable() and not self._misfit()),
                         # main's rule: the 1-sigma stopped falling at the landmark-free drift floor
                         "old_rule": bool(searched and self._drift_limited() and self._stable() and not self._misfit()),
                         "estimate": self.estimate.dwell if self.estimate else None, "stops": out is not None})
        return out

    SearchBrain.stop_rule = recording
    try:
        r = fly_offline(load_scene(scene_name), SearchConfig(strategy="info", bound_fall_m_s=0.0), seed=seed)
    finally:
        SearchBrain.stop_rule = original
    src = r.dataset.truth.sources[0]
    frames = r.dataset.frames
    dwell = np.asarray(frames.dwell)
    ends = {int(k): float(np.max(frames.t[dwell == k])) for k in np.unique(dwell[dwell >= 0])}
    t_done = max(ends.values())
    by_dwell = {e.dwell: e for e in r.brain.estimates}
    for s in seen:
        e = by_dwell.get(s["estimate"])
        s["t"] = r.mission_time_s - (t_done - ends[s["dwells"] - 1])
        s["error_m"] = math.hypot(e.x - src.x, e.y - src.y) if e else math.nan
        s["covered_95"] = covered(e, src) if e else None
    return {"scene": scene_name, "seed": seed, "mission_time_s": r.mission_time_s, "error_m": r.error_m,
            "decisions": seen}


def covered(estimate, src) -> bool | None:
    """Whether the estimate's 95 % x-y ellipse holds the true source (None: no finite ellipse)."""
    cov = np.asarray(estimate.covariance, dtype=float)[:2, :2]
    if not (math.isfinite(estimate.sigma_m) and np.isfinite(cov).all()):
        return None
    d = np.array([estimate.x - src.x, estimate.y - src.y])
    return bool(d @ np.linalg.pinv(cov) @ d <= -2.0 * math.log(0.05))


def stopped_at(row: dict, threshold: float | None) -> dict:
    """The decision where the rule with ``threshold`` (None: main's drift-floor rule) stops the flight (the
    flight's end if never)."""
    for d in row["decisions"]:
        if (d["old_rule"] if threshold is None else d["eligible"] and d["fall_m_s"] < threshold):
            return d
    return row["decisions"][-1] if row["decisions"] else {"t": row["mission_time_s"], "error_m": row["error_m"],
                                                          "covered_95": None}


def se(v: np.ndarray) -> float:
    """Standard error of the mean of v."""
    return float(v.std(ddof=1) / math.sqrt(len(v))) if len(v) > 1 else math.nan


def table(rows: list[dict], allowance: float) -> list[str]:
    """Per scene and stop rule: median error and time, the share over the allowance, 95 % coverage, and the
    paired error and time against main's rule (mean +- standard error)."""
    out = ["| scene (flights) | stop rule | median error (m) | median time (s) | p90 time (s) | share over allowance "
           "| 95 % coverage | error - main's rule (m) | time - main's rule (s) |",
           "|---|---|---|---|---|---|---|---|---|"]
    for scene in sorted({r["scene"] for r in rows}):
        sub = [r for r in rows if r["scene"] == scene]
        main = [stopped_at(r, None) for r in sub]
        for x in (None, *THRESHOLDS):
            at = [stopped_at(r, x) for r in sub]
            t = np.array([d["t"] for d in at])
            e = np.array([d["error_m"] for d in at])
            cov = [d["covered_95"] for d in at if d["covered_95"] is not None]
            de = e - np.array([d["error_m"] for d in main])
            dt = t - np.array([d["t"] for d in main])
            name = "main (drift floor)" if x is None else f"fall < {1e3 * x:g} mm/s"
            out.append(f"| {scene} ({len(sub)}) | {name} | {np.median(e):.3f} | {np.median(t):.0f} "
                       f"| {np.percentile(t, 90):.0f} | {np.mean(t > allowance):.2f} | {np.mean(cov):.2f} "
                       f"| {de.mean():+.4f} +- {se(de):.4f} | {dt.mean():+.1f} +- {se(dt):.1f} |")
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", nargs="+", default=["default", "lattice-wall"])
    p.add_argument("--seed0", type=int, default=1000)
    p.add_argument("--seeds", type=int, default=30)
    p.add_argument("--out", help="JSON lines, one flight each (appended; flights already there are skipped)")
    p.add_argument("--read", help="only summarise this file")
    p.add_argument("--allowance", type=float, default=78.0, help="s, 0.6 x the lattice's median mission time")
    args = p.parse_args(argv)
    path = Path(args.read or args.out) if (args.read or args.out) else None
    rows = [json.loads(x) for x in path.read_text().splitlines()] if path and path.exists() else []
    if not args.read:
        done = {(r["scene"], r["seed"]) for r in rows}
        for scene in args.scenes:
            for seed in range(args.seed0, args.seed0 + args.seeds):
                if (scene, seed) in done:
                    continue
                row = fly(scene, seed)
                rows.append(row)
                if path:
                    with path.open("a") as f:
                        f.write(json.dumps(row) + "\n")
    print("\n".join(table(rows, args.allowance)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
