"""Error against mission time per search strategy, from a campaign folder (``benchmarks/mission_search.py --out``
or ``radseek campaign --out``): one panel per scene, every flight a dot, each strategy's median error at its
median mission time a cross, and the 0.6 x lattice time line of issue 36's target. Several folders: a
(scene, strategy) flown in a later folder replaces the earlier folders' flights of it (a rerun after a change).

    python benchmarks/planner_error_time.py CAMPAIGN_DIR [CAMPAIGN_DIR ...] --png docs/img/planner-error-time.png
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from launch.campaign_store import DamagedStore, load_rows

COLOURS = {"info": "tab:green", "active": "tab:blue", "lattice": "tab:orange", "lawnmower": "tab:grey"}


def medians(rows: list[dict]) -> dict[tuple[str, str], tuple[float, float, int]]:
    """(scene, strategy) -> (median mission time s, median x-y error m, flights) over the ok rows."""
    out: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for r in rows:
        if r["status"] == "ok":
            out.setdefault((r["scene"], r["strategy"]), []).append((r["mission_time_s"], r["error_m"]))
    return {k: (float(np.median([a for a, _ in v])), float(np.median([b for _, b in v])), len(v))
            for k, v in out.items()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("campaign", type=Path, nargs="+", help="campaign folders (their Parquet rows)")
    p.add_argument("--png", type=Path, required=True, help="figure to write")
    args = p.parse_args(argv)
    rows: list[dict] = []
    for folder in args.campaign:
        try:
            got = load_rows(folder)
        except (DamagedStore, OSError) as exc:
            print(f"planner_error_time: {folder}: {exc}", file=sys.stderr)
            return 2
        if not got:
            print(f"planner_error_time: {folder}: no flights recorded", file=sys.stderr)
            return 2
        cases = {(r["scene"], r["strategy"]) for r in got}
        rows = [r for r in rows if (r["scene"], r["strategy"]) not in cases] + got
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    med = medians(rows)
    scenes = sorted({s for s, _ in med})
    fig, axes = plt.subplots(1, len(scenes), figsize=(5.5 * len(scenes), 4.2), squeeze=False)
    for ax, scene in zip(axes[0], scenes, strict=True):
        for strategy in sorted({st for s, st in med if s == scene}):
            pts = np.array([(r["mission_time_s"], r["error_m"]) for r in rows
                            if r["status"] == "ok" and r["scene"] == scene and r["strategy"] == strategy])
            c = COLOURS.get(strategy, "black")
            ax.scatter(pts[:, 0], pts[:, 1], s=8, alpha=0.35, color=c)
            t, e, n = med[(scene, strategy)]
            ax.scatter([t], [e], marker="X", s=140, color=c, edgecolor="black", label=f"{strategy} (median, {n})")
        if (scene, "lattice") in med:
            ax.axvline(0.6 * med[(scene, "lattice")][0], ls="--", color="grey", lw=1, label="0.6 x lattice time")
            ax.axhline(med[(scene, "lattice")][1], ls=":", color="tab:orange", lw=1)
        ax.set_yscale("log")
        ax.set_xlabel("mission time (simulated s)")
        ax.set_ylabel("x-y error (m)")
        ax.set_title(scene)
        ax.legend(fontsize=8)
    fig.tight_layout()
    args.png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.png, dpi=110)
    print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
