"""Error against mission time per search strategy, and issue 36's targets, from campaign folders
(``benchmarks/mission_search.py --out`` or ``radseek campaign --out``).

The table: per (scene, strategy) the flights, found (outcome found or drift-limited; the fixed patterns have no
stop rule), 95 % ellipse coverage with its Wilson 95 % interval, median x-y error with its distribution-free 95 %
interval, median drift-aware bound (the final estimate's ``bound_m``), median error over it, median mission time,
median CPU per search. Then, per scene flown by both, the information search against the lattice over the seeds
both flew (issue 36: info's median error <= the lattice's at <= 0.6 x the lattice's median mission time), and
every case against the per-scene targets (found >= 0.95, coverage in [0.93, 0.97], median error <= 1.1 x the
median bound).

The figure: one panel per scene flown by more than one strategy, every flight a dot, each strategy's median
error at its median mission time a cross, and the 0.6 x lattice time line. Several folders: a (scene, strategy)
flown in a later folder replaces the earlier folders' flights of it (a rerun after a change).

    python benchmarks/planner_error_time.py CAMPAIGN_DIR [CAMPAIGN_DIR ...] --png docs/img/planner-error-time.png
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from scipy import stats

from launch.campaign import median_ci, wilson
from launch.campaign_store import DamagedStore, load_rows
from radseek.outcome import Outcome

COLOURS = {"info": "tab:green", "active": "tab:blue", "lattice": "tab:orange", "lawnmower": "tab:grey"}
#: issue 36's targets: found share, coverage band, median error over median bound, share of the lattice's time
FOUND_MIN, COVERAGE_BAND, ERROR_PER_BOUND, TIME_SHARE = 0.95, (0.93, 0.97), 1.1, 0.6
#: strategies with a stop rule (the fixed patterns end "pattern flown": found does not apply)
SEARCHES = ("active", "info")


def medians(rows: list[dict]) -> dict[tuple[str, str], tuple[float, float, int]]:
    """(scene, strategy) -> (median mission time s, median x-y error m, flights) over the ok rows."""
    out: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for r in rows:
        if r["status"] == "ok":
            out.setdefault((r["scene"], r["strategy"]), []).append((r["mission_time_s"], r["error_m"]))
    return {k: (float(np.median([a for a, _ in v])), float(np.median([b for _, b in v])), len(v))
            for k, v in out.items()}


def case_summary(rows: list[dict]) -> dict:
    """The table's figures for the ok rows of one (scene, strategy)."""
    err = np.array([r["error_m"] for r in rows], dtype=float)
    bound = np.array([r["bound_m"] for r in rows], dtype=float)
    cov = [bool(r["covered_95"]) for r in rows if r["covered_95"] is not None]
    found = sum(r["outcome"] is not None and Outcome(r["outcome"]).found for r in rows)
    med, lo, hi, _ = median_ci(err)
    b = float(np.nanmedian(bound)) if np.isfinite(bound).any() else math.nan
    return {"runs": len(rows), "found": found, "covered": sum(cov), "cov_n": len(cov),
            "coverage": sum(cov) / len(cov) if cov else math.nan, "coverage_ci": wilson(sum(cov), len(cov)),
            "error": med, "error_ci": (lo, hi), "bound": b, "error_per_bound": med / b,
            "time": float(np.median([r["mission_time_s"] for r in rows])),
            "cpu": float(np.median([r["cpu_s"] for r in rows])),
            "seeds": (min(r["seed"] for r in rows), max(r["seed"] for r in rows))}


def paired(a: list[dict], b: list[dict], rng: np.random.Generator, draws: int = 4000) -> dict:
    """Strategy ``a`` against ``b`` over the seeds both flew: error difference (mean +- standard error, paired
    median, difference of medians with its paired-bootstrap 95 % interval), mission time ratio of the medians
    with its paired-bootstrap 95 % interval, and in how many seeds ``a`` was the more accurate."""
    ea, eb = ({r["seed"]: r for r in rows} for rows in (a, b))
    seeds = sorted(set(ea) & set(eb))
    x = np.array([[ea[s]["error_m"], eb[s]["error_m"], ea[s]["mission_time_s"], eb[s]["mission_time_s"]]
                  for s in seeds], dtype=float)
    d = x[:, 0] - x[:, 1]
    idx = rng.integers(0, len(seeds), (draws, len(seeds)))
    boot = np.median(x[idx], axis=1)  # (draws, 4): medians of each column per resample
    dmed = boot[:, 0] - boot[:, 1]
    ratio = boot[:, 2] / boot[:, 3]
    med = np.median(x, axis=0)
    return {"n": len(seeds), "mean": float(d.mean()), "se": float(d.std(ddof=1) / math.sqrt(len(d))),
            "paired_median": float(np.median(d)), "better": int((d < 0).sum()),
            "diff_medians": float(med[0] - med[1]), "diff_ci": tuple(np.percentile(dmed, [2.5, 97.5])),
            "time_ratio": float(med[2] / med[3]), "ratio_ci": tuple(np.percentile(ratio, [2.5, 97.5]))}


def report(rows: list[dict], rng: np.random.Generator | None = None) -> list[str]:
    """The table, the paired comparisons and the targets' verdicts as Markdown lines."""
    rng = rng if rng is not None else np.random.default_rng(36)
    cases: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        if r["status"] == "ok":
            cases.setdefault((r["scene"], r["strategy"]), []).append(r)
    summ = {k: case_summary(v) for k, v in sorted(cases.items())}
    out = ["| scene | strategy | runs (seeds) | found | 95 % coverage [Wilson 95 %] | median error (m) [95 % CI] "
           "| median bound (m) | error / bound | median mission (s) | CPU / search (s) |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for (scene, strategy), s in summ.items():
        found = f"{s['found'] / s['runs']:.3f}" if strategy in SEARCHES else "-"
        out.append(f"| {scene} | {strategy} | {s['runs']} ({s['seeds'][0]}-{s['seeds'][1]}) | {found} "
                   f"| {s['coverage']:.3f} [{s['coverage_ci'][0]:.3f}, {s['coverage_ci'][1]:.3f}] "
                   f"| {s['error']:.3f} [{s['error_ci'][0]:.3f}, {s['error_ci'][1]:.3f}] | {s['bound']:.3f} "
                   f"| {s['error_per_bound']:.2f} | {s['time']:.0f} | {s['cpu']:.1f} |")
    pairs = [(scene, first) for scene in sorted({sc for sc, _ in summ}) for first in SEARCHES
             if (scene, first) in cases and (scene, "lattice") in cases]
    if pairs:
        out += ["", "| scene | pair | seeds | error difference, mean +- se (m) | paired median (m) | first better "
                "| difference of medians (m) [95 %] | median time ratio [95 %] | target |",
                "|---|---|---|---|---|---|---|---|---|"]
    for scene, first in pairs:
        p = paired(cases[(scene, first)], cases[(scene, "lattice")], rng)
        met = p["diff_medians"] <= 0 and p["time_ratio"] <= TIME_SHARE
        out.append(f"| {scene} | {first} - lattice | {p['n']} | {p['mean']:+.4f} +- {p['se']:.4f} "
                   f"| {p['paired_median']:+.4f} | {p['better']} of {p['n']} | {p['diff_medians']:+.4f} "
                   f"[{p['diff_ci'][0]:+.4f}, {p['diff_ci'][1]:+.4f}] | {p['time_ratio']:.2f} "
                   f"[{p['ratio_ci'][0]:.2f}, {p['ratio_ci'][1]:.2f}] | {'met' if met else 'NOT met'} |")
    out += ["", "| scene | strategy | found >= 0.95 | coverage in [0.93, 0.97] | median error <= 1.1 x bound "
            "| coverage against 0.95: exact binomial p (two-sided) | a calibrated ellipse in the band |",
            "|---|---|---|---|---|---|---|"]
    for (scene, strategy), s in summ.items():
        if strategy not in SEARCHES:
            continue
        verdict = [s["found"] / s["runs"] >= FOUND_MIN, COVERAGE_BAND[0] <= s["coverage"] <= COVERAGE_BAND[1],
                   s["error"] <= ERROR_PER_BOUND * s["bound"]]
        n = s["cov_n"]
        out.append(f"| {scene} | {strategy} | " + " | ".join("met" if v else "NOT met" for v in verdict)
                   + f" | {coverage_p(int(s['covered']), n):.2f} | {band_chance(n):.2f} |")
    return out


def coverage_p(covered: int, n: int, level: float = 0.95) -> float:
    """Exact two-sided binomial p of ``covered`` of ``n`` ellipses holding the truth, if each holds it with
    probability ``level``: how well the coverage agrees with a calibrated ellipse (nan without flights)."""
    return float(stats.binomtest(covered, n, level).pvalue) if n else math.nan


def band_chance(n: int, level: float = 0.95) -> float:
    """The probability that ``n`` calibrated ellipses (each holding the truth with probability ``level``) give a
    coverage in :data:`COVERAGE_BAND`: at 200 flights 0.86, so 10 calibrated cases all land in it 22 % of the
    time; at 400 flights 0.95 (60 %)."""
    if not n:
        return math.nan
    lo, hi = math.ceil(COVERAGE_BAND[0] * n - 1e-9), math.floor(COVERAGE_BAND[1] * n + 1e-9)
    b = stats.binom(n, level)
    return float(b.cdf(hi) - b.cdf(lo - 1))


def plot(rows: list[dict], png: Path) -> None:
    """The error-against-time figure of the scenes flown by more than one strategy."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    med = medians(rows)
    scenes = sorted(s for s in {s for s, _ in med} if sum(sc == s for sc, _ in med) > 1)
    if not scenes:
        return
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
            ax.axvline(TIME_SHARE * med[(scene, "lattice")][0], ls="--", color="grey", lw=1,
                       label="0.6 x lattice time")
            ax.axhline(med[(scene, "lattice")][1], ls=":", color="tab:orange", lw=1)
        ax.set_yscale("log")
        ax.set_xlabel("mission time (simulated s)")
        ax.set_ylabel("x-y error (m)")
        ax.set_title(scene)
        ax.legend(fontsize=8)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    print(f"wrote {png}")


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
    print("\n".join(report(rows)))
    plot(rows, args.png)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
