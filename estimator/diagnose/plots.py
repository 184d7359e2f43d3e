"""PNG plots of where the model fails (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from estimator.diagnose.features import unit_of  # noqa: E402
from estimator.diagnose.residuals import broken_at_gaps, group_mean  # noqa: E402

if TYPE_CHECKING:
    from estimator.diagnose.runner import ModelReport
    from estimator.spectral import SpectralFit


def _label(rep: ModelReport) -> str:
    return "baseline" + "".join(f" + {e}" for e in rep.effects)


def plot_features(rep: ModelReport, path: Path, title: str = "") -> Path:
    """Relative residual (observed/expected - 1) binned against each feature, with Poisson error bars."""
    names = list(rep.trends)
    ncol = 3
    nrow = max(1, -(-len(names) // ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.1 * nrow), squeeze=False)
    lab = rep.segment_labels
    feats = rep.features.scalar_features()
    n = rep.counts
    mu = np.asarray(rep.fit.expected, dtype=float)
    from estimator.diagnose.residuals import aggregate

    sn, smu = aggregate(lab, n, mu)
    srel = sn / np.maximum(smu, 1e-9) - 1.0
    for ax, name in zip(axes.ravel(), names, strict=False):
        tr = rep.trends[name]
        x_seg = group_mean(lab, feats[name], mu)
        ax.scatter(x_seg, srel, s=4, color="0.75", label="per segment")
        # the line breaks across empty bins (no frames there): NaN between the segments
        cx, rel, err = broken_at_gaps(tr, tr.centres, tr.rel, tr.rel_err)
        ax.errorbar(cx, rel, yerr=err, fmt="o-", color="C3" if tr.p_value < 0.01 else "C0",
                    ms=4, label=f"binned, chi2 {tr.chi2:.0f}/{tr.dof}")
        ax.axhline(0, color="k", lw=0.8)
        lim = max(0.05, float(np.nanmax(np.abs(tr.rel) + 2 * tr.rel_err)) * 1.3)
        ax.set_ylim(-lim, lim)
        if name in ("count rate", "distance"):
            ax.set_xscale("log")
        ax.set_xlabel(f"{name} [{unit_of(name)}]")
        ax.set_ylabel("observed / expected - 1")
        ax.legend(fontsize=7, loc="best")
    for ax in axes.ravel()[len(names):]:
        ax.axis("off")
    fig.suptitle(title or f"Residuals of {_label(rep)}: deviance/dof {rep.gof.deviance_per_dof:.3f}")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_map(rep: ModelReport, path: Path, scenario=None, title: str = "") -> Path:
    """Per-segment Pearson residuals at their positions (a residual map), with the fitted source(s)."""
    lab = rep.segment_labels
    f = rep.features
    x, y = group_mean(lab, f.x), group_mean(lab, f.y)
    fig, ax = plt.subplots(figsize=(6.4, 5.2))
    r = np.clip(rep.segment_pearson, -6, 6)
    sc = ax.scatter(x, y, c=r, cmap="coolwarm", vmin=-6, vmax=6, s=18 + 6 * np.abs(r), edgecolors="k",
                    linewidths=0.3)
    fig.colorbar(sc, ax=ax, label="Pearson residual per segment (clipped at +-6)")
    for i, s in enumerate(rep.sources):
        ax.plot(s["x"], s["y"], marker="*", ms=16, color="gold", mec="k", label="fitted source" if i == 0 else None)
    if scenario is not None:
        for w in scenario.walls:
            ax.plot([w.start[0], w.end[0]], [w.start[1], w.end[1]], color="0.3", lw=4, alpha=0.6)
    from estimator.diagnose.shadow import seen_part
    from estimator.diagnose.verdict import unmapped_walls

    src = np.array([rep.fit.values.get("x", np.nan), rep.fit.values.get("y", np.nan)])
    for i, w in enumerate(unmapped_walls(rep.fit)):
        # the slab as fitted, thin and dashed; the part the lines of sight cross (what the counts locate), thick
        ax.plot([w["start"][0], w["end"][0]], [w["start"][1], w["end"][1]], color="C2", lw=1.5, ls="--", alpha=0.8,
                label="unmapped wall as fitted" if i == 0 else None)
        seen = seen_part(src, w["start"], w["end"], np.c_[f.x, f.y])
        if seen is not None:
            ax.plot([seen["start"][0], seen["end"][0]], [seen["start"][1], seen["end"][1]], color="C2", lw=5,
                    alpha=0.9, label=f"its part the lines of sight cross (mu x t {w['mu_x_thickness']:.2f})"
                    if i == 0 else None)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(loc="best", fontsize=8)
    ax.set_title(title or f"Residual map, {_label(rep)}")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_spectral(spec: SpectralFit, path: Path, null: bool = True, title: str = "") -> Path:
    """Pearson residuals of the spectral model per time group (rows) and channel (columns)."""
    r = spec.pearson(null=null)
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    im = ax.imshow(np.clip(r, -5, 5), aspect="auto", origin="lower", cmap="coolwarm", vmin=-5, vmax=5,
                   extent=(-0.5, r.shape[1] - 0.5, spec.group_t[0], spec.group_t[-1]))
    fig.colorbar(im, ax=ax, label="Pearson residual")
    ax.set_xlabel("channel")
    ax.set_ylabel("time [s]")
    what = "no gain drift" if null else f"gain drift {spec.percent_per_min:+.3f} %/min"
    ax.set_title(title or f"Spectral residuals, channel over time ({what})")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_before_after(before: ModelReport, after: ModelReport, path: Path) -> Path:
    """Per-segment Pearson residuals over time, before and after adding the effect(s)."""
    fig, axes = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True, sharey=True)
    for ax, rep in zip(axes, (before, after), strict=True):
        t = group_mean(rep.segment_labels, rep.features.time_s)
        ax.plot(t, rep.segment_pearson, ".", ms=3)
        ax.axhline(0, color="k", lw=0.8)
        for v in (-2, 2):
            ax.axhline(v, color="0.6", lw=0.6, ls="--")
        ax.set_ylabel("Pearson residual")
        ax.set_title(f"{_label(rep)}: deviance/dof {rep.gof.deviance_per_dof:.3f}, residual RMS "
                     f"{rep.residual_rms:.2f}", fontsize=10)
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
