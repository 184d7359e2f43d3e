"""Measured vs model spectra with residuals (``radseek calibrate --plot``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def energy_upper_keV(problem, res) -> float:
    """The energy axis's upper end (keV): the spectrum's end (1.4 x the energy below which 99.5 % of its net counts
    lie), far enough to show every channel the model misses by more than 3 sigma and every still-missing window the
    text names (``spectra.fit.residual_regions``: the plot stopped at 1 MeV while the text named 1.7-2.1 MeV)."""
    from spectra.fit import residual_regions

    b = problem.boundaries
    centre = 0.5 * (b[1:] + b[:-1])
    net = problem.net()
    m = problem.mask & (centre > 0)
    upper = 1.4 * float(centre[m][np.argmax(np.cumsum(net[m]) > 0.995 * net[m].sum())])
    mu = np.maximum(res.expected, 1e-9)
    missed = m & (np.abs((problem.n - mu) / np.sqrt(mu)) > 3)
    if missed.any():
        upper = max(upper, 1.05 * float(centre[missed].max()))
    for w in residual_regions(problem, res):
        upper = max(upper, 1.03 * float(w["to_keV"]))
    return float(min(b[-1], max(upper, 200.0)))


def plot_fit(problem, res, base, path: str | Path, title: str = "") -> Path:
    """Three panels: native spectrum (measured net, calibrated model, emulator's response) on a log scale;
    Pearson residuals of the calibrated model; the 32 board channels above 60 keV as normalised shapes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from spectra.fit import TV_MIN_KEV, _rebin_signed, reference_edges, residual_regions, shape_distances

    b = problem.boundaries
    centre = 0.5 * (b[1:] + b[:-1])
    width = np.diff(b)
    lt = problem.spectrum.livetime
    net = problem.net()
    m = problem.mask & (centre > 0)
    fig, ax = plt.subplots(3, 1, figsize=(10, 11), gridspec_kw={"height_ratios": [3, 1.3, 2]})
    ax[0].step(centre[m], np.clip(net[m] / width[m] / lt, 1e-5, None), where="mid", color="k", lw=0.7,
               label="measured minus background" if problem.background is not None else "measured")
    ax[0].plot(centre[m], np.clip(res.shape[m] / width[m] / lt, 1e-5, None), color="C3", lw=1.2,
               label=f"calibrated response (deviance/dof {res.deviance_per_dof:.2f})")
    ax[0].plot(centre[m], np.clip(base.shape[m] / width[m] / lt, 1e-5, None), color="C0", lw=0.9, ls="--",
               label=f"emulator's response before calibration (deviance/dof {base.deviance_per_dof:.1f})")
    ax[0].set_yscale("log")
    ax[0].set_ylabel("counts / keV / s")
    mu = np.maximum(res.expected, 1e-9)
    pr = (problem.n - mu) / np.sqrt(mu)
    ax[0].set_xlim(0, energy_upper_keV(problem, res))
    for i, w in enumerate(residual_regions(problem, res)):  # the windows the text names as still missing
        ax[0].axvspan(w["from_keV"], w["to_keV"], color="C1", alpha=0.12, lw=0,
                      label="still missing (named in the text)" if i == 0 else None)
    ax[0].legend(fontsize=8)
    ax[0].set_title(title)
    ax[1].plot(centre[m], np.clip(pr[m], -8, 8), ".", ms=2, color="C3")
    ax[1].set_ylim(-8.5, 8.5)  # clipped at +-8 so that channels where the model is ~0 do not hide the rest
    ax[1].axhline(0, color="k", lw=0.5)
    ax[1].set_ylabel("Pearson residual")
    ax[1].set_xlim(ax[0].get_xlim())
    ax[1].set_xlabel("energy (keV, file calibration)")
    edges = reference_edges()
    keep = edges[:-1] >= TV_MIN_KEV
    meas32 = np.maximum(_rebin_signed(net, b, edges)[keep], 0)
    ok = b[:-1] >= 0
    mod32 = _rebin_signed(np.where(ok, res.shape, 0), b, edges)[keep]
    base32 = _rebin_signed(np.where(ok, base.shape, 0), b, edges)[keep]
    x = np.arange(keep.sum())
    d, d0 = shape_distances(problem, res.shape, edges), shape_distances(problem, base.shape, edges)
    ax[2].bar(x - 0.27, meas32 / meas32.sum(), 0.27, color="k", label="measured")
    ax[2].bar(x, mod32 / mod32.sum(), 0.27, color="C3",
              label=f"calibrated (TV {d['total_variation_32']:.3f})")
    ax[2].bar(x + 0.27, base32 / base32.sum(), 0.27, color="C0",
              label=f"before calibration (TV {d0['total_variation_32']:.3f})")
    lo = edges[:-1][keep]
    ax[2].set_xticks(x[::3], [f"{v:.0f}" for v in lo[::3]])
    ax[2].set_xlabel("board channel (lower edge, keV)")
    ax[2].set_ylabel("share of counts above 60 keV")
    ax[2].legend(fontsize=8)
    fig.tight_layout()
    p = Path(path)
    fig.savefig(p, dpi=90)
    plt.close(fig)
    return p
