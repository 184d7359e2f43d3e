"""The run report: what a person looks at after a mission (``report.png``) and ``summary.json``.

Panels: the map (walls, flown path, dwell points scaled by rate, the final estimate with its 1- and
2-sigma ellipses against the truth); error, 1-sigma and Gaussian entropy (paper 000 eq. 15) against
dwell number; the recorded spectrum per dwell; the count rate over time.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Ellipse, Polygon  # noqa: E402

from radseek.dataset import Dataset, read_dataset  # noqa: E402
from radseek.outdir import atomic_path, atomic_write_json  # noqa: E402


def gaussian_entropy(cov: np.ndarray) -> float:
    """Differential entropy of a Gaussian, 0.5 ln((2 pi e)^k det C) (paper 000 eq. 15)."""
    cov = np.atleast_2d(cov)
    sign, logdet = np.linalg.slogdet(cov)
    if sign <= 0:
        return float("nan")
    k = cov.shape[0]
    return float(0.5 * (k * math.log(2 * math.pi * math.e) + logdet))


def _ellipse(ax, mean, cov, n_sigma, **kw) -> None:
    w, v = np.linalg.eigh(cov)
    w = np.clip(w, 0, None)
    angle = math.degrees(math.atan2(v[1, -1], v[0, -1]))
    ax.add_patch(Ellipse(mean, 2 * n_sigma * math.sqrt(w[-1]), 2 * n_sigma * math.sqrt(w[0]), angle=angle,
                         fill=False, **kw))


def _wall_polygon(w) -> np.ndarray:
    s, e = np.array(w.start), np.array(w.end)
    u = (e - s) / max(np.linalg.norm(e - s), 1e-9)
    n = np.array([-u[1], u[0]]) * w.thickness / 2
    return np.array([s + n, e + n, e - n, s - n])


def final_fit(ds: Dataset):
    """The MLE of the whole recorded flight (baseline model, pose uncertainty), for the report."""
    from estimator.localizers.base import make_localizer

    return make_localizer("mle").fit(ds.frames, ds.scenario)


def write_report(out: str | Path, wall_time_s: float | None = None, speedup: float | None = None) -> dict[str, Any]:
    from estimator.inflight import sigma_m

    out = Path(out)
    ds = read_dataset(out / "dataset")
    mission = json.loads((out / "dataset" / "mission_summary.json").read_text())
    loc = final_fit(ds)
    src = loc.sources_[0]
    cov = np.asarray(loc.covariance_, dtype=float)[:2, :2]
    truth = ds.truth
    err = math.hypot(src["x"] - truth.sources[0].x, src["y"] - truth.sources[0].y) if truth else math.nan
    f = ds.frames

    fig, axes = plt.subplots(2, 2, figsize=(13, 10))
    ax = axes[0, 0]
    for w in ds.scenario.walls:
        ax.add_patch(Polygon(_wall_polygon(w), color="0.45", alpha=0.8))
    ax.plot(f.x, f.y, "-", color="0.6", lw=0.8, label="flown path (estimated pose)")
    dwells = sorted(set(f.dwell[f.dwell >= 0].tolist()))
    rates = []
    for k in dwells:
        m = f.dwell == k
        rates.append(f.total_counts[m].sum() / f.duration[m].sum())
        ax.scatter(f.x[m].mean(), f.y[m].mean(), s=20 + 200 * math.sqrt(rates[-1] / max(1.0, max(rates))),
                   color="tab:orange", edgecolor="k", zorder=3)
        ax.annotate(str(k), (f.x[m].mean(), f.y[m].mean()), xytext=(4, 4), textcoords="offset points", fontsize=8)
    ax.plot(src["x"], src["y"], "b+", ms=14, mew=2, label=f"estimate ({src['x']:.2f}, {src['y']:.2f})")
    _ellipse(ax, (src["x"], src["y"]), cov, 1, color="b", lw=1.2)
    _ellipse(ax, (src["x"], src["y"]), cov, 2, color="b", lw=0.8, ls="--")
    if truth:
        for s in truth.all_sources():
            ax.plot(s.x, s.y, "r*", ms=14, label="truth" if s is truth.sources[0] else None)
    lo, hi = ds.scenario.bounds_min, ds.scenario.bounds_max
    ax.set_xlim(lo[0] - 0.5, hi[0] + 0.5)
    ax.set_ylim(lo[1] - 0.5, hi[1] + 0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.set_title(f"map: {len(dwells)} dwell points (size ~ rate), error {err:.3f} m")
    ax.legend(fontsize=8, loc="upper right")

    ax = axes[0, 1]
    est = mission.get("estimates", [])
    if est and truth:
        k = [e["dwell"] for e in est]
        e_err = [math.hypot(e["x"] - truth.sources[0].x, e["y"] - truth.sources[0].y) for e in est]
        sig = [e["sigma_m"] for e in est]
        ax.semilogy(k, e_err, "o-", label="position error (m)")
        ax.semilogy(k, sig, "s--", label="1-sigma semi-major axis (m)")
        ax.axhline(0.15, color="0.5", lw=0.8, ls=":", label="0.15 m target")
        ax.set_xlabel("dwell points flown")
        ax.set_ylabel("m")
        ax2 = ax.twinx()
        ent = [gaussian_entropy(np.diag([max(s, 1e-6) ** 2] * 2)) if math.isfinite(s) else math.nan for s in sig]
        ax2.plot(k, ent, "^:", color="tab:green", label="Gaussian entropy (nats)")
        ax2.set_ylabel("entropy (nats, paper 000 eq. 15)")
        ax.legend(fontsize=8, loc="upper right")
        ax2.legend(fontsize=8, loc="lower left")
    ax.set_title("convergence")

    ax = axes[1, 0]
    edges = ds.scenario.channel_edges_keV
    centres = 0.5 * (edges[:-1] + edges[1:])
    for k in dwells:
        m = f.dwell == k
        spec = f.counts[m].sum(0) / f.duration[m].sum() / np.diff(edges)
        ax.semilogy(centres, np.maximum(spec, 1e-4), drawstyle="steps-mid", lw=0.8, label=f"dwell {k}")
    ax.set_xlabel("energy (keV, comparator channel centres)")
    ax.set_ylabel("rate density (cps/keV)")
    ax.set_title("spectra per dwell point")
    if len(dwells) <= 10:
        ax.legend(fontsize=7, ncol=2)

    ax = axes[1, 1]
    ax.plot(f.t, f.total_counts / f.duration, ",", color="0.3")
    for k in dwells:
        m = f.dwell == k
        ax.axvspan(f.t[m].min(), f.t[m].max(), color="tab:orange", alpha=0.2)
    ax.set_yscale("log")
    ax.set_xlabel("sim time (s)")
    ax.set_ylabel("total count rate (cps)")
    ax.set_title("count rate (dwells shaded)")
    fig.suptitle(f"radseek run: {mission.get('reason', '')}", fontsize=11)
    fig.tight_layout()
    with atomic_path(out / "report.png") as tmp:  # a reader never sees half a PNG
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)

    summary = {
        "error_m": err,
        "dwell_points": int(mission["dwell_points"]),
        "search_dwell_points": int(mission.get("search_dwell_points", 0)),
        "mission_time_s": float(mission["mission_time_s"]),
        "flight_time_s": float(mission.get("flight_time_s", math.nan)),
        "estimate": {**src, "background_cps": float(loc.background_),
                     "sigma_m": sigma_m(loc.covariance_, bool(loc.info_.get("converged", True))),
                     "sigma_xy_m": [float(v) for v in np.sqrt(np.clip(np.diag(cov), 0, None))]},
        "in_flight_estimate": mission.get("estimate"),
        "truth": truth.to_dict() if truth else None,
        "stop_reason": mission.get("reason"),
        "frames_received": mission.get("frames_received"),
        "frames_recorded": mission.get("frames_recorded"),
        "frames_flagged": mission.get("frames_flagged"),
        "wall_time_s": wall_time_s,
        "speedup": speedup,
    }
    atomic_write_json(out / "summary.json", summary)  # last, and whole or not at all
    return summary
