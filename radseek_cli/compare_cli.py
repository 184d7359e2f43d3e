"""``radseek compare A B``: replay two datasets of the same flight through the particle filter and plot
the paper 000 run metrics side by side (the simulator-vs-real comparison).

Both datasets are replayed through :class:`estimator.localizers.particle_filter.ParticleFilter` with the
same settings and seeds. Per update the plot shows the total variance (eq. 13) and the Gaussian entropy
(eq. 15) of each run, and the KL divergence D_KL(A || B) (eq. 16) between the two clouds' Gaussian fits
at matching times (each A update paired with the B update nearest in time). With ``--runs K`` each dataset
is replayed with K seeds (thin lines, like the paper's five simulated runs) and the mean is drawn thick.

Example::

    radseek compare real-flight/ simulated-flight/ --out compare.png
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from estimator.localizers.particle_filter import ParticleFilter
from estimator.metrics import kl_gaussian
from radseek.dataset import Dataset, DatasetError
from radseek_io.dataset import read_dataset

__all__ = ["main", "replay", "kl_curve"]


def replay(ds: Dataset, seed: int = 0, **settings: Any) -> list[dict[str, Any]]:
    """The particle filter's per-update history over a dataset (truth unused)."""
    pf = ParticleFilter(seed=seed, **settings).fit(ds.frames, ds.scenario)
    return pf.history_


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
    return p


def main(argv: list[str] | None = None) -> int:
    args = _build_parser().parse_args(argv)
    try:
        da, db = read_dataset(args.a), read_dataset(args.b)
    except DatasetError as exc:
        print(f"radseek compare: {exc}", file=sys.stderr)
        return 2
    settings = {"n_particles": args.n_particles, "dead_time_s": args.dead_time}
    runs_a = [replay(da, args.seed + k, **settings) for k in range(max(args.runs, 1))]
    runs_b = [replay(db, args.seed + k, **settings) for k in range(max(args.runs, 1))]

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for runs, name, color in ((runs_a, da.name, "tab:green"), (runs_b, db.name, "tab:orange")):
        for k, hist in enumerate(runs):
            for ax, key in zip(axes[:2], ("total_variance", "entropy"), strict=True):
                t, v = _series(hist, key)
                ax.plot(t, v, color=color, lw=1.8 if len(runs) == 1 else 0.6, alpha=1 if len(runs) == 1 else 0.5,
                        label=name if k == 0 and len(runs) == 1 else None)
        if len(runs) > 1:  # runs of one dataset share the update times (same frames): draw their mean thick
            for ax, key in zip(axes[:2], ("total_variance", "entropy"), strict=True):
                t, _ = _series(runs[0], key)
                mean = np.mean([_series(h, key)[1] for h in runs], axis=0)
                ax.plot(t, mean, color=color, lw=2.2, label=f"{name} (mean of {len(runs)})")
    kls = [kl_curve(ra, rb) for ra, rb in zip(runs_a, runs_b, strict=True)]
    for t, kl in kls:
        axes[2].plot(t, np.where(np.isfinite(kl), kl, np.nan), color="tab:blue", lw=1.2)
    axes[0].set(title="total variance (eq. 13)", xlabel="t [s]", ylabel="m²", yscale="log")
    axes[1].set(title="Gaussian entropy (eq. 15)", xlabel="t [s]", ylabel="nats")
    axes[2].set(title=f"KL divergence D({da.name} || {db.name}) (eq. 16)", xlabel="t [s]", ylabel="nats",
                yscale="symlog")
    axes[0].legend()
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(f"particle-filter runs: {da.name} vs {db.name} ({args.n_particles} particles, {args.runs} run(s))")
    fig.tight_layout()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)

    summary = {
        "a": str(da.path), "b": str(db.path), "plot": str(out),
        "final_total_variance": [runs_a[0][-1]["total_variance"], runs_b[0][-1]["total_variance"]],
        "final_entropy": [runs_a[0][-1]["entropy"], runs_b[0][-1]["entropy"]],
        "median_kl": float(np.nanmedian(np.where(np.isfinite(kls[0][1]), kls[0][1], np.nan))),
        "final_kl": float(kls[0][1][-1]),
        "updates": [len(runs_a[0]) - 1, len(runs_b[0]) - 1],
    }
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"wrote {out}: total variance {summary['final_total_variance'][0]:.3g} vs "
              f"{summary['final_total_variance'][1]:.3g} m², entropy {summary['final_entropy'][0]:.2f} vs "
              f"{summary['final_entropy'][1]:.2f} nats, median KL {summary['median_kl']:.3g} nats")
    return 0


if __name__ == "__main__":
    sys.exit(main())
