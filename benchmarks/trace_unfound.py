"""Trace why seeded searches end unfound (issue 36 item 2): fly each seed with ``launch.offline.fly_offline`` and
keep, at every stop decision, which part of ``mission.search.SearchBrain.stop_rule`` held (searched, 1-sigma,
stable, misfit, the drift-limited tests: plateau, at the floor, floor within ``AT_FLOOR`` of the pose sd) and
the search budget, then the outcome, error and coverage. One JSON line per flight; ``--read`` tabulates the
unfound flights' last decisions.

    python benchmarks/trace_unfound.py --scene outdoor --strategy active --seeds 60 --out runs/unfound.jsonl
    python benchmarks/trace_unfound.py --read runs/unfound.jsonl
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np


def fly(scene_name: str, strategy: str, seed: int) -> dict:
    """One flight: its stop decisions (what each test said) and how it ended."""
    from detector_fw_sim.scene import load_scene
    from launch.campaign import coverage
    from launch.offline import fly_offline
    from mission.search import AT_FLOOR, PLATEAU, SearchBrain, SearchConfig

    seen: list[dict] = []
    original = SearchBrain.stop_rule
    # before d33f0fc every search dwell spent the budget: the script also traces that code
    budget = getattr(SearchBrain, "_budget_dwells", lambda brain: brain.search_dwells)

    def recording(self, belief, sigma, bound_fall_m_s=None):
        out = original(self, belief, sigma, bound_fall_m_s)
        ests = self.estimates
        now = ests[-1] if ests else None
        before = [e for e in ests[-3:-1] if now is not None and now.dwell - e.dwell <= 2]
        s_before = min((e.sigma_m for e in before), default=math.nan)
        seen.append({
            "dwells": len(self.history), "search_dwells": self.search_dwells, "budget_dwells": budget(self),
            "sigma_m": sigma, "floor_m": now.drift_floor_m if now else math.nan,
            "pose_sd_m": now.pose_sd_m if now else math.nan, "p": now.p_value if now else math.nan,
            "s_before": s_before, "stable": self._stable(), "misfit": bool(self._misfit()),
            "plateau": bool(now is not None and now.sigma_m >= PLATEAU * s_before),
            "at_floor": bool(now is not None and now.sigma_m <= AT_FLOOR * now.drift_floor_m),
            "floor_is_drift": bool(now is not None and now.drift_floor_m <= AT_FLOOR * now.pose_sd_m),
            "drift_limited": self._drift_limited(), "stops": None if out is None else str(out[1])})
        return out

    SearchBrain.stop_rule = recording
    try:
        r = fly_offline(load_scene(scene_name), SearchConfig(strategy=strategy), seed=seed)
    finally:
        SearchBrain.stop_rule = original
    last = r.decisions[-1]
    est = r.estimate
    src = r.dataset.truth.sources[0]
    _, covered = coverage(est, (src.x, src.y))
    return {"scene": scene_name, "strategy": strategy, "seed": seed, "outcome": str(last.outcome),
            "reason": last.reason, "error_m": r.error_m, "mission_time_s": r.mission_time_s,
            "dwells": len(r.brain.history), "covered_95": covered, "decisions": seen}


def table(rows: list[dict]) -> list[str]:
    """Per flight not found: outcome, dwells and the last decisions' tests."""
    out = [f"{len(rows)} flights, found {np.mean([r['outcome'] in ('found', 'drift_limited') for r in rows]):.3f}, "
           f"median error {np.median([r['error_m'] for r in rows]):.3f} m, "
           f"median time {np.median([r['mission_time_s'] for r in rows]):.0f} s, coverage "
           f"{np.mean([bool(r['covered_95']) for r in rows if r['covered_95'] is not None]):.3f}"]
    for r in rows:
        if r["outcome"] in ("found", "drift_limited"):
            continue
        out.append(f"seed {r['seed']}: {r['outcome']} after {r['dwells']} dwells, error {r['error_m']:.3f} m, "
                   f"{r['mission_time_s']:.0f} s: {r['reason']}")
        for d in r["decisions"][-4:]:
            out.append("   " + ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in d.items()))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", default="outdoor")
    p.add_argument("--strategy", default="active")
    p.add_argument("--seed0", type=int, default=0)
    p.add_argument("--seeds", type=int, default=60)
    p.add_argument("--out", help="JSON lines, one flight each (appended; flights already there are skipped)")
    p.add_argument("--read", help="only summarise this file")
    args = p.parse_args(argv)
    path = Path(args.read or args.out) if (args.read or args.out) else None
    rows = [json.loads(x) for x in path.read_text().splitlines()] if path and path.exists() else []
    if not args.read:
        done = {(r["scene"], r["strategy"], r["seed"]) for r in rows}
        for seed in range(args.seed0, args.seed0 + args.seeds):
            if (args.scene, args.strategy, seed) in done:
                continue
            row = fly(args.scene, args.strategy, seed)
            rows.append(row)
            if path:
                with path.open("a") as f:
                    f.write(json.dumps(row) + "\n")
    print("\n".join(table([r for r in rows if r["scene"] == args.scene and r["strategy"] == args.strategy])))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
