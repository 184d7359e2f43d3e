"""What more flight time buys: the in-flight estimate's error along each flight, with the stop rule off
(issue 36: would the information planner reach the lattice's error if it spent up to 0.6 x the lattice's time?).

Each seed is flown with ``launch.offline.fly_offline`` (the one world of ``benchmarks/mission_search.py``) with
``stop_sigma_m`` ~0 and no drift-limited stop, so the active strategies fly on to ``--max-search-dwells``; the
lattice flies its pattern as always. Every in-flight estimate (one per dwell) is kept with its mission time (the
end of that dwell: when the stop rule would decide), its x-y error against the truth, its 1-sigma and the rms of
its x-y covariance. A stop rule stops the same flight at one of these estimates (the planner does not look at the
stop rule), so "the last estimate by time T" is what a rule stopping by T would have reported.

Prints, per scene, the median error of the last estimate by each time in ``--times`` (and by 0.6 x the lattice's
median time when the lattice is flown), paired differences against the lattice at the same seeds, and writes the
rows (one JSON object per flight) and a figure of the medians along the flight.

    python benchmarks/error_along_flight.py --scenes default lattice-wall --strategies info lattice --seeds 30 \\
        --seed0 1000 --jobs 1 --out runs/along.jsonl --png docs/img/planner-error-along-flight.png
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

#: s, the mission times the table reports
TIMES = (50.0, 60.0, 70.0, 80.0, 100.0, 130.0)


def fly(scene_name: str, strategy: str, seed: int, max_search_dwells: int,
        dwell_s: tuple[float, ...] | None = None) -> dict:
    """One flight with the stop rule off: its estimates along the flight (mission time, error, sigma, rms)."""
    from detector_fw_sim.scene import load_scene
    from launch.offline import fly_offline
    from mission.search import SearchConfig

    config = SearchConfig(strategy=strategy, stop_sigma_m=1e-6, stop_at_drift_floor=False,
                          max_search_dwells=max_search_dwells)
    if dwell_s:
        info = dataclasses.replace(config.next_best.info, dwell_lengths_s=tuple(dwell_s))
        config = dataclasses.replace(config, next_best=dataclasses.replace(config.next_best, info=info))
    r = fly_offline(load_scene(scene_name), config, seed=seed)
    src = r.dataset.truth.sources[0]
    frames = r.dataset.frames
    dwell = np.asarray(frames.dwell)
    ends = {int(k): float(np.max(frames.t[dwell == k])) for k in np.unique(dwell[dwell >= 0])}
    t_done = max(ends.values())
    along = []
    for e in r.brain.estimates:
        end = ends.get(e.dwell - 1)
        if end is None:
            continue
        cov = np.asarray(e.covariance, dtype=float)[:2, :2]
        along.append({"dwell": e.dwell, "t": r.mission_time_s - (t_done - end),
                      "error_m": math.hypot(e.x - src.x, e.y - src.y), "sigma_m": e.sigma_m,
                      "rms_m": math.sqrt(max(float(np.trace(cov)), 0.0))})
    return {"scene": scene_name, "strategy": strategy, "seed": seed, "mission_time_s": r.mission_time_s,
            "error_m": r.error_m, "along": along}


def error_by(row: dict, t: float) -> float:
    """The error of the flight's last estimate made by mission time ``t`` (nan if none yet)."""
    got = [a["error_m"] for a in row["along"] if a["t"] <= t]
    return got[-1] if got else math.nan


def paired(a: list[float], b: list[float]) -> str:
    """Mean +- standard error of a - b over the pairs where both are known."""
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    d = d[np.isfinite(d)]
    if len(d) < 2:
        return "-"
    se = d.std(ddof=1) / math.sqrt(len(d))
    return f"{d.mean():+.4f} +- {se:.4f} m over {len(d)} seeds (median {np.median(d):+.4f})"


def report(rows: list[dict], times: tuple[float, ...] = TIMES, base_s: float = 60.0) -> list[str]:
    """Markdown lines: per scene and strategy the median error by each time; paired against the strategy's own
    estimate by ``base_s`` (what more time buys) and against the lattice flown out."""
    lines = []
    for scene in sorted({r["scene"] for r in rows}):
        at = {s: {r["seed"]: r for r in rows if r["scene"] == scene and r["strategy"] == s}
              for s in sorted({r["strategy"] for r in rows if r["scene"] == scene})}
        ts = list(times)
        if "lattice" in at:
            ts.append(0.6 * float(np.median([r["mission_time_s"] for r in at["lattice"].values()])))
            ts.append(float(np.max([r["mission_time_s"] for r in at["lattice"].values()])))
        ts = sorted(set(round(t, 1) for t in ts))
        lines.append(f"\n{scene}: median x-y error (m) of the last estimate by mission time t (flights with one)")
        lines.append("| strategy | flights | " + " | ".join(f"t <= {t:g} s" for t in ts) + " |")
        lines.append("|---|---|" + "---|" * len(ts))
        for s, by_seed in at.items():
            cells = []
            for t in ts:
                e = np.array([error_by(r, t) for r in by_seed.values()])
                e = e[np.isfinite(e)]
                cells.append(f"{np.median(e):.3f} ({len(e)})" if len(e) else "-")
            lines.append(f"| {s} | {len(by_seed)} | " + " | ".join(cells) + " |")
        for s, by_seed in at.items():
            if s == "lattice":
                continue
            for t in ts:
                if t > base_s:
                    mine = [(error_by(r, t), error_by(r, base_s)) for r in by_seed.values()]
                    lines.append(f"{scene}: {s} by {t:g} s - {s} by {base_s:g} s: "
                                 + paired([a for a, _ in mine], [b for _, b in mine]))
            if "lattice" not in at:
                continue
            lattice = at["lattice"]
            seeds = sorted(set(by_seed) & set(lattice))
            for t in ts[:-1]:
                lines.append(f"{scene}: {s} by {t:g} s - lattice flown out: " + paired(
                    [error_by(by_seed[k], t) for k in seeds], [error_by(lattice[k], ts[-1]) for k in seeds]))
    return lines


def plot(rows: list[dict], png: Path) -> None:
    """Median error along the flight (last estimate by t) per strategy, one panel per scene."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from benchmarks.planner_error_time import COLOURS

    scenes = sorted({r["scene"] for r in rows})
    fig, axes = plt.subplots(1, len(scenes), figsize=(5.5 * len(scenes), 4.2), squeeze=False)
    grid = np.arange(20.0, 181.0, 2.0)
    for ax, scene in zip(axes[0], scenes, strict=True):
        lattice_t = None
        for s in sorted({r["strategy"] for r in rows if r["scene"] == scene}):
            flights = [r for r in rows if r["scene"] == scene and r["strategy"] == s]
            e = np.array([[error_by(r, t) for t in grid] for r in flights])
            n = np.isfinite(e).sum(0)
            keep = n >= 0.5 * len(flights)  # a median of most flights, not of the few that have an estimate
            med = np.array([np.median(c[np.isfinite(c)]) if k else np.nan for c, k in zip(e.T, keep, strict=True)])
            ax.plot(grid, med, color=COLOURS.get(s, "black"), label=f"{s} ({len(flights)} flights)")
            if s == "lattice":
                lattice_t = float(np.median([r["mission_time_s"] for r in flights]))
        if lattice_t is not None:
            ax.axvline(0.6 * lattice_t, ls="--", color="grey", lw=1, label="0.6 x lattice time")
        ax.set_ylim(0.0, 0.3)
        ax.set_xlabel("mission time (simulated s)")
        ax.set_ylabel("median x-y error of the last estimate (m)")
        ax.set_title(f"{scene}, stop rule off")
        ax.legend(fontsize=8)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", nargs="+", default=["default", "lattice-wall"])
    p.add_argument("--strategies", nargs="+", default=["info", "lattice"])
    p.add_argument("--seeds", type=int, default=30)
    p.add_argument("--seed0", type=int, default=0, help="first seed (tune on 1000+, report on 0..N)")
    p.add_argument("--max-search-dwells", type=int, default=8)
    p.add_argument("--dwell-s", type=float, nargs="+", help="the information planner's dwell lengths (s)")
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--niceness", type=int, default=10)
    p.add_argument("--out", type=Path, help="JSON lines, one per flight; flights already there are not flown again")
    p.add_argument("--png", type=Path)
    args = p.parse_args(argv)
    rows: list[dict] = []
    if args.out and args.out.exists():
        rows = [json.loads(line) for line in args.out.read_text().splitlines() if line.strip()]
    done = {(r["scene"], r["strategy"], r["seed"]) for r in rows}
    todo = [(sc, st, s) for sc in args.scenes for st in args.strategies
            for s in range(args.seed0, args.seed0 + args.seeds) if (sc, st, s) not in done]
    if todo:
        os.nice(args.niceness)
        with ProcessPoolExecutor(args.jobs) as pool:
            futures = [pool.submit(fly, sc, st, s, args.max_search_dwells, args.dwell_s) for sc, st, s in todo]
            for fut in futures:
                row = fut.result()
                rows.append(row)
                if args.out:
                    args.out.parent.mkdir(parents=True, exist_ok=True)
                    with args.out.open("a") as f:
                        f.write(json.dumps(row) + "\n")
    seeds = set(range(args.seed0, args.seed0 + args.seeds))
    rows = [r for r in rows if r["scene"] in args.scenes and r["strategy"] in args.strategies and r["seed"] in seeds]
    print("\n".join(report(rows)))
    if args.png:
        plot(rows, args.png)
        print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
