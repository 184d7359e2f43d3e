"""``radseek compare A B``: replay two datasets of the same flight through the particle filter and plot
the paper 000 run metrics side by side (the simulator-vs-real comparison).

Both datasets are replayed through :class:`estimator.localizers.particle_filter.ParticleFilter` with the
same settings and seeds. Per update the plot shows the total variance (eq. 13) and the Gaussian entropy
(eq. 15) of each run, and the KL divergence D_KL(A || B) (eq. 16) between the two clouds' Gaussian fits
at matching times (each A update paired with the B update nearest in time). With ``--runs K`` each dataset
is replayed with K seeds (thin lines, like the paper's five simulated runs) and the mean is drawn thick.

Both inputs must be the same flight: the same scenario geometry (bounds, walls, source height, channel edges)
and the same dwell points (as many, each within :data:`SAME_DWELL_M` of the other's). Two different flights are
refused with what differs (exit 2); ``--allow-different`` draws them anyway, titled as different flights.

A particle cloud can collapse: resampling leaves a few distinct particles and its variance falls to 1e-6 m^2
while no estimator could know the source that well from these counts. Each update's total variance is compared
with the Cramér-Rao bound of the frames recorded up to then (at the filter's final estimate, poses taken as
exact, with the filter's uniform prior as a Gaussian of its variance, :func:`crlb_floor`): a decade below it
(:data:`COLLAPSE_FRACTION`) the plot draws the variance at that floor, dotted, shades the span and says
so, and the command warns; the JSON summary gives ``collapsed_at`` (the first such time, or null) per input.

Example::

    radseek compare real-flight/ simulated-flight/ --out compare.png
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from estimator.localizers.particle_filter import ParticleFilter
from estimator.metrics import kl_gaussian
from radseek.dataset import Dataset, DatasetError
from radseek_io.dataset import read_dataset

__all__ = ["COLLAPSE_FRACTION", "SAME_DWELL_M", "crlb_floor", "flight_differences", "fingerprint", "main", "replay",
           "kl_curve"]

#: m: dwell points of the same flight recorded twice (a real flight and its simulated twin) lie this close
SAME_DWELL_M = 0.5


def replay(ds: Dataset, seed: int = 0, **settings: Any) -> list[dict[str, Any]]:
    """The particle filter's per-update history over a dataset (truth unused)."""
    return replay_filter(ds, seed, **settings).history_


def replay_filter(ds: Dataset, seed: int = 0, **settings: Any) -> ParticleFilter:
    """The particle filter fitted to a dataset (its ``history_`` per update, its final estimate)."""
    return ParticleFilter(seed=seed, **settings).fit(ds.frames, ds.scenario)


def _geometry(ds: Dataset) -> dict[str, Any]:
    sc = ds.scenario
    return {"bounds_min": np.round(sc.bounds_min, 3).tolist(), "bounds_max": np.round(sc.bounds_max, 3).tolist(),
            "source_z": round(float(sc.source_z), 3), "channels": len(sc.channel_edges_keV) - 1,
            "channel_edges_keV": np.round(sc.channel_edges_keV, 1).tolist(),
            "walls": [repr(w) for w in sc.walls]}


def _dwell_points(ds: Dataset) -> np.ndarray:
    """(K, 3) mean recorded position of each dwell, in order of its first frame."""
    f = ds.frames
    ks = [k for k in dict.fromkeys(f.dwell.tolist()) if k >= 0]
    return np.array([[f.x[f.dwell == k].mean(), f.y[f.dwell == k].mean(), f.z[f.dwell == k].mean()]
                     for k in ks]).reshape(-1, 3)


def fingerprint(ds: Dataset) -> str:
    """A short hash of the scenario's geometry and the dwell points (rounded to 0.5 m): equal for two recordings
    of one flight (real and simulated), shown so a user can tell inputs apart."""
    pts = np.round(_dwell_points(ds) / SAME_DWELL_M).astype(int).tolist()
    blob = json.dumps({"scenario": _geometry(ds), "dwells": pts}, sort_keys=True).encode()
    return hashlib.sha256(blob).hexdigest()[:12]


def flight_differences(a: Dataset, b: Dataset) -> list[str]:
    """What makes ``a`` and ``b`` two different flights ([] when they are one flight recorded twice): scenario
    geometry, number of dwells, dwell points farther apart than :data:`SAME_DWELL_M`."""
    out = []
    ga, gb = _geometry(a), _geometry(b)
    diff = [k for k in ga if ga[k] != gb[k]]
    if diff:
        out.append(f"scenario differs ({', '.join(diff)})")
    pa, pb = _dwell_points(a), _dwell_points(b)
    if len(pa) != len(pb):
        out.append(f"{len(pa)} dwells vs {len(pb)}")
    else:
        far = np.flatnonzero(np.hypot(*(pa[:, :2] - pb[:, :2]).T) > SAME_DWELL_M)
        if len(far):
            k = int(far[0])
            out.append(f"{len(far)} of {len(pa)} dwell points more than {SAME_DWELL_M} m apart (dwell {k}: "
                       f"({pa[k, 0]:.2f}, {pa[k, 1]:.2f}) vs ({pb[k, 0]:.2f}, {pb[k, 1]:.2f}))")
    return out


def crlb_floor(ds: Dataset, pf: ParticleFilter) -> np.ndarray:
    """Per update of ``pf.history_``: the total variance (eq. 13) of the Cramér-Rao bound of the source position
    given the frames recorded up to that update (Poisson Fisher information over x, y, cps_at_1m and background,
    poses taken as exact, the filter's final estimate as the point). No estimate of these counts is more certain:
    a cloud whose variance is below it has collapsed (too few distinct particles left), not converged."""
    from estimator.metrics import total_variance_from_cov
    from estimator.mle import expected_count_gradient
    from estimator.model import MeasurementModel

    f = ds.frames
    model = MeasurementModel(ds.scenario)
    s = pf.sources_[0]
    theta = {"x": s["x"], "y": s["y"], "z": float(ds.scenario.source_z), "cps_at_1m": max(s["cps_at_1m"], 1e-3),
             "background_cps": max(float(pf.background_), 1e-3)}
    names = ["x", "y", "cps_at_1m", "background_cps"]
    g = expected_count_gradient(model, theta, f, names)
    mu = np.maximum(model.expected_counts({**model.defaults(), **theta}, f), 1e-12)
    cum = np.cumsum(g[:, :, None] * g[:, None, :] / mu[:, None, None], axis=0)
    # the filter's prior as the information of Gaussians of its variances (x, y uniform over the bounds: L^2 / 12;
    # activity gamma: shape scale^2; background uniform over its range): before the counts tell more, the prior is
    # the floor (its cloud is no collapse), and one dwell's rank-deficient information still inverts
    span = np.asarray(ds.scenario.bounds_max[:2], float) - np.asarray(ds.scenario.bounds_min[:2], float)
    b_lo, b_hi = (r * max(float(ds.scenario.background_cps), 1.0) for r in pf.background_range)
    var = [*(np.maximum(span, 1e-6) ** 2 / 12.0), pf.activity_shape * pf.activity_scale**2,
           max(b_hi - b_lo, 1e-6) ** 2 / 12.0]
    prior = np.diag(1.0 / np.asarray(var, dtype=float))
    out = []
    for h in pf.history_:
        i = int(np.searchsorted(f.t, h["t"], side="right"))
        out.append(total_variance_from_cov(np.linalg.pinv(prior + (cum[i - 1] if i > 0 else 0.0))))
    return np.array(out)


#: a cloud whose total variance is below this fraction of the floor has collapsed. A healthy posterior sits near
#: or above the bound, and the floor's approximations (the bound taken at the final estimate, the prior as a
#: Gaussian) move it by a factor of a few early on (lattice-clean, 20000 particles: 0.32 after its second dwell,
#: 3.7-43 later); a collapse is decades (lattice-wall: 1.8e-6 m² at a floor of 2.5e-4 m², 0.007)
COLLAPSE_FRACTION = 0.1


def _collapsed(hist: list[dict[str, Any]], floor: np.ndarray) -> np.ndarray:
    return np.array([h["total_variance"] for h in hist]) < COLLAPSE_FRACTION * floor


def _collapsed_at(hist: list[dict[str, Any]], floor: np.ndarray) -> float | None:
    below = np.flatnonzero(_collapsed(hist, floor))
    return float(hist[int(below[0])]["t"]) if len(below) else None


def kl_curve(hist_a: list[dict[str, Any]], hist_b: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray]:
    """Times of A's updates and D_KL(A || B) against B's update nearest in time (eq. 16)."""
    tb = np.array([h["t"] for h in hist_b])
    ts, kl = [], []
    for h in hist_a:
        j = int(np.argmin(np.abs(tb - h["t"])))
        ts.append(h["t"])
        kl.append(kl_gaussian(h["mean"], h["cov"], hist_b[j]["mean"], hist_b[j]["cov"]))
    return np.array(ts), np.array(kl)


def _series(hist: list[dict[str, Any]], key: str) -> tuple[np.ndarray, np.ndarray]:
    return np.array([h["t"] for h in hist]), np.array([h[key] for h in hist])


def plot_path(out: str | Path) -> Path:
    """The file ``--out`` names: a folder gets ``compare.png`` inside, a name without a suffix gets ``.png`` (as
    matplotlib would add it; the summary then names the file that exists, not ``--out`` as typed)."""
    out = Path(out)
    if out.is_dir():
        return out / "compare.png"
    return out if out.suffix else out.with_suffix(".png")


def _build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="radseek compare", description=__doc__.split("\n")[0])
    p.add_argument("a", help="first dataset (e.g. the real flight)")
    p.add_argument("b", help="second dataset of the same flight (e.g. the simulated one)")
    p.add_argument("--out", default="runs/compare.png", help="PNG to write (default runs/compare.png)")
    p.add_argument("--runs", type=int, default=1, help="particle-filter seeds per dataset (default 1)")
    p.add_argument("--n-particles", type=int, default=100_000)
    p.add_argument("--dead-time", type=float, default=0.0, help="detector dead time a (s) in the likelihood")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="also print the curves' summary as JSON")
    p.add_argument("--allow-different", action="store_true",
                   help="draw two different flights side by side anyway (default: refused, naming what differs)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _build_parser().parse_args(argv)
    try:
        da, db = read_dataset(args.a), read_dataset(args.b)
    except DatasetError as exc:
        print(f"radseek compare: {exc}", file=sys.stderr)
        return 2
    differences = flight_differences(da, db)
    prints = (fingerprint(da), fingerprint(db))
    if differences:
        what = (f"{args.a} (fingerprint {prints[0]}) and {args.b} (fingerprint {prints[1]}) are not the same flight: "
                f"{'; '.join(differences)}")
        if not args.allow_different:
            print(f"radseek compare: {what}; compare two recordings of one flight (say a real flight and its "
                  "simulated twin), or pass --allow-different", file=sys.stderr)
            return 2
        print(f"radseek compare: warning: {what}; drawn anyway (--allow-different): the KL divergence then "
              "compares two different problems", file=sys.stderr)
    settings = {"n_particles": args.n_particles, "dead_time_s": args.dead_time}
    runs_a = [replay_filter(da, args.seed + k, **settings) for k in range(max(args.runs, 1))]
    runs_b = [replay_filter(db, args.seed + k, **settings) for k in range(max(args.runs, 1))]
    floors = {id(pf): crlb_floor(ds, pf) for runs, ds in ((runs_a, da), (runs_b, db)) for pf in runs}
    collapsed = [[_collapsed_at(pf.history_, floors[id(pf)]) for pf in runs] for runs in (runs_a, runs_b)]
    for name, cs, runs in ((da.name, collapsed[0], runs_a), (db.name, collapsed[1], runs_b)):
        n = sum(c is not None for c in cs)
        if n:
            pf = runs[next(i for i, c in enumerate(cs) if c is not None)]
            low = _collapsed(pf.history_, floors[id(pf)])
            tv = np.array([h["total_variance"] for h in pf.history_])
            j = int(np.argmin(np.where(low, tv / floors[id(pf)], np.inf)))
            print(f"radseek compare: warning: {name}: the particle cloud collapsed in {n} of {len(cs)} run(s) (from "
                  f"t = {min(c for c in cs if c is not None):.1f} s; at t = {pf.history_[j]['t']:.1f} s its total "
                  f"variance {tv[j]:.2g} m² against a Cramér-Rao floor of {floors[id(pf)][j]:.2g} m² for the counts "
                  "so far): too few distinct particles, not certainty; its variance, entropy and KL say nothing "
                  "there (drawn at the floor, dotted, shaded)", file=sys.stderr)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from estimator.metrics import entropy_from_cov

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for runs, name, color in ((runs_a, da.name, "tab:green"), (runs_b, db.name, "tab:orange")):
        one = len(runs) == 1
        for k, pf in enumerate(runs):
            hist, floor = pf.history_, floors[id(pf)]
            t = np.array([h["t"] for h in hist])
            tv = np.array([h["total_variance"] for h in hist])
            low = _collapsed(hist, floor)
            ent = np.array([h["entropy"] for h in hist])
            # below the floor the cloud says nothing: drawn at the floor, dotted, its entropy likewise
            ent_floor = np.array([entropy_from_cov(np.diag([f / np.sqrt(2), f / np.sqrt(2)])) if np.isfinite(f)
                                  else -np.inf for f in floor])
            for ax, v, vf in ((axes[0], tv, floor), (axes[1], ent, ent_floor)):
                real = np.where(low, np.nan, v)
                ax.plot(t, real, color=color, lw=1.8 if one else 0.6, alpha=1 if one else 0.5,
                        label=name if k == 0 and one else None)
                if low.any():
                    held = np.where(low | np.r_[low[1:], False], np.maximum(v, vf), np.nan)
                    ax.plot(t, held, color=color, lw=1.4, ls=":", marker=".", ms=3,
                            label=f"{name}: collapsed, held at the Cramér-Rao floor" if k == 0 else None)
            if k == 0:
                axes[0].plot(t, floor, color=color, lw=0.8, ls="--", alpha=0.7,
                             label=f"{name}: Cramér-Rao floor of its counts")
            if low.any():
                for ax in axes:
                    ax.axvspan(t[low][0], t[-1], color=color, alpha=0.08, lw=0)
        if len(runs) > 1:  # runs of one dataset share the update times (same frames): draw their mean thick
            for ax, key in zip(axes[:2], ("total_variance", "entropy"), strict=True):
                t, _ = _series(runs[0].history_, key)
                mean = np.mean([_series(pf.history_, key)[1] for pf in runs], axis=0)
                ax.plot(t, mean, color=color, lw=2.2, label=f"{name} (mean of {len(runs)})")
    kls = [kl_curve(ra.history_, rb.history_) for ra, rb in zip(runs_a, runs_b, strict=True)]
    for t, kl in kls:
        axes[2].plot(t, np.where(np.isfinite(kl), kl, np.nan), color="tab:blue", lw=1.2)
    axes[0].set(title="total variance (eq. 13)", xlabel="t [s]", ylabel="m²", yscale="log")
    axes[1].set(title="Gaussian entropy (eq. 15)", xlabel="t [s]", ylabel="nats")
    axes[2].set(title=f"KL divergence D({da.name} || {db.name}) (eq. 16)", xlabel="t [s]", ylabel="nats",
                yscale="symlog")
    axes[0].legend(fontsize=7)
    for ax in axes:
        ax.grid(alpha=0.3)
    head = f"particle-filter runs: {da.name} vs {db.name} ({args.n_particles} particles, {args.runs} run(s))"
    if differences:
        head = f"DIFFERENT FLIGHTS (not comparable): {da.name} vs {db.name}: {'; '.join(differences)}"
    if any(c is not None for cs in collapsed for c in cs):
        head += "\nshaded: a cloud collapsed below the Cramér-Rao floor of its counts (not certainty)"
    fig.suptitle(head, fontsize=10)
    fig.tight_layout()
    out = plot_path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)

    last_a, last_b = runs_a[0].history_[-1], runs_b[0].history_[-1]
    summary = {
        "a": str(da.path), "b": str(db.path), "plot": str(out),
        "fingerprints": list(prints), "same_flight": not differences, "differences": differences,
        "final_total_variance": [last_a["total_variance"], last_b["total_variance"]],
        "floor_total_variance": [float(floors[id(runs_a[0])][-1]), float(floors[id(runs_b[0])][-1])],
        "collapsed_at": [collapsed[0][0], collapsed[1][0]],
        "final_entropy": [last_a["entropy"], last_b["entropy"]],
        "median_kl": float(np.nanmedian(np.where(np.isfinite(kls[0][1]), kls[0][1], np.nan))),
        "final_kl": float(kls[0][1][-1]),
        "updates": [len(runs_a[0].history_) - 1, len(runs_b[0].history_) - 1],
    }
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        flags = ["" if c is None else " (collapsed)" for c in (collapsed[0][0], collapsed[1][0])]
        print(f"wrote {out}: total variance {summary['final_total_variance'][0]:.3g}{flags[0]} vs "
              f"{summary['final_total_variance'][1]:.3g}{flags[1]} m² (Cramér-Rao floors "
              f"{summary['floor_total_variance'][0]:.3g} and {summary['floor_total_variance'][1]:.3g} m²), entropy "
              f"{summary['final_entropy'][0]:.2f} vs {summary['final_entropy'][1]:.2f} nats, median KL "
              f"{summary['median_kl']:.3g} nats")
    return 0


if __name__ == "__main__":
    sys.exit(main())
