"""The verdict: is the final model adequate, and if not, where does the residual live.

A forward selection can only name effects it knows. After it, the final model's deviance is compared with its
expectation (exact Poisson moments, ``residuals.goodness_of_fit``), and each channel's spectrum over time with the
spectral model's: more than ``ADEQUATE_SD`` standard deviations above (``SPECTRAL_Z`` for a channel), and the
verdict is "the model still misses something none of the candidates explains". The effects the selection added
are then helpers (``partial``), not the missing physics; with an adequate fit they are ``missing``. Either way
``hotspots`` ranks where the residual lives: segments (dwells, 1 s of transit), directions from the fitted source,
times, and spectral channels, each as a z-score of observed against expected counts.

Unmapped walls are reported in the scenario's own ``walls`` form (dataset-format.md) with ``material:
"unmapped"``, ``mu_per_m`` and 1-sigma uncertainties propagated from the fit's covariance, so that a user can paste
them into scenario.json.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from estimator.diagnose.backend import WALLS
from estimator.diagnose.dispersion import fit_dispersion
from estimator.diagnose.residuals import (
    GoodnessOfFit,
    aggregate,
    deviance_moments,
    goodness_of_fit,
    group_mean,
    pose_penalty,
    unit_deviance,
)
from estimator.diagnose.shadow import seen_part
from estimator.model import UnmappedWall
from radseek.dataset import Frames

if TYPE_CHECKING:
    from estimator.diagnose.runner import ModelReport

#: an AIC difference read as strong support for one model over another (Burnham and Anderson): the off-list
#: checks (``motion``, ``background_time``) add their look-elsewhere allowance to it
STRONG_AIC = 10.0


def off_list_threshold(looks: int) -> float:
    """The AIC gap an off-list check needs: :data:`STRONG_AIC` plus the look-elsewhere allowance 2 ln(looks), for
    the best of ``looks`` alternatives (break times, period starts) fitted against the named model."""
    return STRONG_AIC + 2 * math.log(looks)


def aic_gap(named: Any, alternative: Any) -> float:
    """AIC of the ``named`` FitResult minus the ``alternative``'s on the same frames (positive: the alternative is
    better)."""
    return 2 * (named.nll - alternative.nll) + 2 * (len(named.free_names) - len(alternative.free_names))


#: a fitted source whose strength is below this many of its standard errors is not called a source: its position is
#: wherever the counts' noise peaked (the fit maximises over position, so 2 sigma is what noise alone often gives)
SOURCE_SIGMA = 3.0


def source_reading(cps_at_1m: float, sd: float | None) -> str | None:
    """A plain line when a fitted source is not above background (strength below ``SOURCE_SIGMA`` errors, or no
    finite error), else None: a walk with no source must not read as a found one."""
    if sd is not None and math.isfinite(sd) and sd > 0 and cps_at_1m >= SOURCE_SIGMA * sd:
        return None
    err = f"{cps_at_1m:.3g} +- {sd:.2g}" if sd is not None and math.isfinite(sd) else f"{cps_at_1m:.3g}, no error"
    return (f"no source above background: cps_at_1m {err} is below {SOURCE_SIGMA:g} standard errors, so its "
            "position is not a measurement")


#: a fit whose deviance is more than this many standard deviations above its expectation is not adequate
ADEQUATE_SD = 3.0
#: a channel whose spectral residual over time is beyond this z (chi-square over time groups) is not adequate
SPECTRAL_Z = 6.0
#: hotspots below this |z| are not listed
HOTSPOT_Z = 3.0
N_DIRECTIONS = 8
N_TIMES = 8


def excess_sd(rep: ModelReport, frames: Frames | None = None, gof: GoodnessOfFit | None = None) -> float:
    """(deviance/dof - expected) / sd of the final model's per-frame goodness of fit (``gof`` if given, else
    :func:`count_gof` when ``frames`` are given)."""
    g = gof or (rep.gof if frames is None else count_gof(rep, frames))
    return (g.deviance_per_dof - g.expected_per_dof) / max(g.sd_per_dof, 1e-12)


def spectral_channel_z(rep: ModelReport) -> np.ndarray:
    """Per channel, the spectral model's Poisson deviance summed over the time groups as a z-score against its
    exact mean and variance (``residuals.deviance_moments``; a Pearson sum explodes on near-empty channels): a
    shape change over time that no spectral effect in the model follows (a background that varies in time, a
    source whose spectrum changes) shows here, not in the total counts."""
    sp = rep.spectral
    if sp is None:
        return np.zeros(0)
    mu = np.maximum(np.asarray(sp.expected_null if "gain_drift" not in rep.effects else sp.expected, float), 1e-12)
    dev = unit_deviance(sp.counts, mu)
    mean, var = deviance_moments(mu)
    return (dev.sum(0) - mean.sum(0)) / np.sqrt(np.maximum(var.sum(0), 1e-12))


def count_gof(rep: ModelReport, frames: Frames) -> GoodnessOfFit:
    """The final model's per-frame goodness of fit with the frames' extra-Poisson variance allowed for: over-
    dispersed counts are not a missing effect (a noisy mount, an unsteady bias), so the expected deviance takes the
    relative variance r^2 measured on pairs of consecutive frames (``dispersion.fit_dispersion``: smooth misfits
    of the mean cancel from a pair, so this does not hide them), as a model with ``over_dispersion`` would."""
    if "over_dispersion" in rep.effects:
        return rep.gof
    n = rep.counts.astype(float)
    mu = np.asarray(rep.fit.expected, dtype=float)
    r2 = max(float(fit_dispersion(frames, mu).rel_sd), 0.0) ** 2
    if r2 <= 0:
        return rep.gof
    return goodness_of_fit(n, mu, len(rep.fit.free_names), penalty=pose_penalty(rep.fit, n, mu), rel_var=r2)


def adequate(rep: ModelReport, frames: Frames | None = None) -> bool:
    """The final model fits the total counts within :data:`ADEQUATE_SD` sd (with the frames' extra-Poisson
    variance, :func:`count_gof`, when ``frames`` are given) and no channel's spectrum over time
    misfits beyond :data:`SPECTRAL_Z` (null flights: at most 2.5 on 18 flights of measured and analytic crystals,
    Co-60 and Cs-137, the shared datasets among them; a background varying by 60 % in time: 14.4)."""
    z = spectral_channel_z(rep)
    return excess_sd(rep, frames) <= ADEQUATE_SD and (len(z) == 0 or float(z.max()) <= SPECTRAL_Z)


def misfit_text(rep: ModelReport, frames: Frames | None = None) -> str:
    """Why the final model is not adequate, for people."""
    g = rep.gof if frames is None else count_gof(rep, frames)
    parts = [f"counts: deviance/dof {g.deviance_per_dof:.3f}, expected {g.expected_per_dof:.3f} +- "
             f"{g.sd_per_dof:.3f}, {excess_sd(rep, gof=g):+.1f} sd"]
    z = spectral_channel_z(rep)
    if len(z):
        parts.append(f"spectrum over time: worst channel {int(np.argmax(z))} at z {float(np.max(z)):.1f} "
                     f"(adequate up to {SPECTRAL_Z:g})")
    return "; ".join(parts)


def _z(n: np.ndarray, mu: np.ndarray) -> np.ndarray:
    return (n - mu) / np.sqrt(np.maximum(mu, 1e-9))


def hotspots(rep: ModelReport, edges_keV: np.ndarray | None = None, limit: int = 10) -> list[dict[str, Any]]:
    """Where the final model's residual lives, most significant first (|z| >= :data:`HOTSPOT_Z`)."""
    f = rep.features
    n = rep.counts.astype(float)
    mu = np.asarray(rep.fit.expected, dtype=float)
    out: list[dict[str, Any]] = []
    # segments: the residual map
    lab = rep.segment_labels
    sx, sy, st = (group_mean(lab, v) for v in (f.x, f.y, f.time_s))
    sn, smu = aggregate(lab, n, mu)
    for i in np.argsort(-np.abs(rep.segment_pearson))[:4]:
        out.append({"kind": "segment", "z": float(rep.segment_pearson[i]),
                    "where": f"t {st[i]:.0f} s at ({sx[i]:.2f}, {sy[i]:.2f}) m",
                    "x": float(sx[i]), "y": float(sy[i]), "t_s": float(st[i]),
                    "observed": float(sn[i]), "expected": float(smu[i])})
    # directions from the fitted (primary) source
    src = rep.sources[0]
    az = np.degrees(np.arctan2(f.y - src["y"], f.x - src["x"])) % 360.0
    k = (az // (360.0 / N_DIRECTIONS)).astype(int)
    dn, dmu = np.bincount(k, n, N_DIRECTIONS), np.bincount(k, mu, N_DIRECTIONS)
    for j in np.flatnonzero(dmu > 0):
        lo = j * 360.0 / N_DIRECTIONS
        out.append({"kind": "direction", "z": float(_z(dn[j], dmu[j])),
                    "where": f"bearing {lo:.0f}-{lo + 360 / N_DIRECTIONS:.0f} deg from the fitted source "
                             "(counter-clockwise from +x)", "bearing_deg": [lo, lo + 360.0 / N_DIRECTIONS],
                    "observed": float(dn[j]), "expected": float(dmu[j])})
    # times
    t = f.time_s
    edges = np.quantile(t, np.linspace(0, 1, N_TIMES + 1))
    k = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, N_TIMES - 1)
    tn, tmu = np.bincount(k, n, N_TIMES), np.bincount(k, mu, N_TIMES)
    for j in np.flatnonzero(tmu > 0):
        out.append({"kind": "time", "z": float(_z(tn[j], tmu[j])), "where": f"t {edges[j]:.0f}-{edges[j + 1]:.0f} s",
                    "t_s": [float(edges[j]), float(edges[j + 1])], "observed": float(tn[j]),
                    "expected": float(tmu[j])})
    # energies: the spectral model's residuals per channel (summed over time groups)
    zc = spectral_channel_z(rep)
    for c in np.argsort(-zc)[:4]:
        rng = "" if edges_keV is None else f" ({edges_keV[c]:.0f}-{edges_keV[c + 1]:.0f} keV)"
        out.append({"kind": "energy", "z": float(zc[c]), "where": f"channel {c}{rng}, spectrum over time",
                    "channel": int(c)})
    out = [h for h in out if math.isfinite(h["z"]) and abs(h["z"]) >= HOTSPOT_Z]
    out.sort(key=lambda h: -abs(h["z"]))
    return out[:limit]


def _wall_errors(fit: Any, wall: str) -> dict[str, float]:
    """1-sigma of the slab's end points and centre, propagated from the fit's covariance (numerical Jacobian)."""
    names = list(fit.free_names)
    cov = np.asarray(fit.covariance, dtype=float)
    base = dict(fit.values)

    def ends(v: dict[str, float]) -> np.ndarray:
        w = UnmappedWall.wall_of(v, wall)
        return np.r_[w[:4], (w[0:2] + w[2:4]) / 2]

    e0 = ends(base)
    jac = np.zeros((len(e0), len(names)))
    for i, nm in enumerate(names):
        h = 1e-4 * max(abs(base[nm]), 1.0)
        jac[:, i] = (ends({**base, nm: base[nm] + h}) - e0) / h
    if cov.shape != (len(names), len(names)) or not np.all(np.isfinite(cov)):
        return {}
    sd = np.sqrt(np.maximum(np.diag(jac @ cov @ jac.T), 0.0))
    return dict(zip(("start_x", "start_y", "end_x", "end_y", "centre_x", "centre_y"), map(float, sd), strict=True))


#: the distance range along the wall's bearing keeps the distances whose -log L is within this of the fit's
#: (1.92: 95 % for one parameter)
DISTANCE_DELTA_NLL = 1.92


def distance_range(fit: Any, frames: Frames, wall: str, n: int = 40) -> tuple[float, float]:
    """The distances from the source, along the wall's fitted bearing, at which the same slab seen under the same
    angle (its length scaled with the distance) explains the counts within :data:`DISTANCE_DELTA_NLL` of the fit:
    a point source's shadow fixes the sector a wall blocks, not where along it the wall stands (paper 004
    eq. 5.19: only the lines of sight through it see it). A profile over that one degenerate direction, the
    other parameters held; the extremes of the accepted distances."""
    v = dict(fit.values)
    r0, length0 = float(v[f"{wall}.r"]), float(v[f"{wall}.length"])
    src = np.array([v["x"], v["y"]])
    far = float(np.hypot(*(frames.positions[:, :2] - src).T).max())
    rs = np.unique(np.r_[np.geomspace(UnmappedWall.MIN_DISTANCE_M, max(far, r0 * 1.01), n), r0])
    obs = fit.model.observed_counts(frames)

    def nll(r: float) -> float:
        ln = float(np.clip(length0 * r / r0, UnmappedWall.MIN_LENGTH_M, UnmappedWall.MAX_LENGTH_M))
        mu = np.maximum(fit.model.expected_counts({**v, f"{wall}.r": r, f"{wall}.length": ln}, frames), 1e-300)
        return float((mu - obs * np.log(mu)).sum())

    values = np.array([nll(float(r)) for r in rs])
    ok = rs[values - values[rs == r0][0] <= DISTANCE_DELTA_NLL]
    return float(ok.min()), float(ok.max())


def unmapped_walls(fit: Any, frames: Frames | None = None) -> list[dict[str, Any]]:
    """The fit's unmapped walls in the scenario's ``walls`` form, with mu_per_m and uncertainties; with ``frames``,
    also the range of distances along the wall's bearing that the shadow allows (:func:`distance_range`) and the
    ``seen_part`` of the slab, the part the flight's lines of sight to the fitted source cross
    (``shadow.seen_part``): the counts locate that part, and the slab's length beyond it is the fit's guess."""
    out = []
    for wall in WALLS:
        if f"{wall}.r" not in fit.values:
            continue
        w = UnmappedWall.wall_of(fit.values, wall)
        mu = float(fit.values[f"{wall}.mu_per_m"])
        err = _wall_errors(fit, wall)
        mu_err = float(fit.errors.get(f"{wall}.mu_per_m", float("nan")))
        extra: dict[str, Any] = {}
        if frames is not None:
            lo, hi = distance_range(fit, frames, wall)
            seen = seen_part(np.array([fit.values["x"], fit.values["y"]]), w[0:2], w[2:4], np.c_[frames.x, frames.y])
            extra = {"distance_from_source_m": round(float(fit.values[f"{wall}.r"]), 3),
                     "distance_range_95_m": [round(lo, 3), round(hi, 3)],
                     "bearing_deg": round(float(fit.values[f"{wall}.phi_deg"]) % 360.0, 1),
                     "seen_part": None if seen is None else {k: [round(c, 3) for c in v] for k, v in seen.items()}}
        out.append({"start": [round(float(w[0]), 3), round(float(w[1]), 3)],
                    "end": [round(float(w[2]), 3), round(float(w[3]), 3)],
                    "thickness": float(w[4]), "height": float(w[5]), "material": "unmapped",
                    "mu_per_m": mu, "mu_x_thickness": mu * float(w[4]), **extra,
                    "errors": {**err, "mu_per_m": mu_err},
                    "note": "a point source's shadow fixes the sector the wall blocks; its distance along those "
                            "lines of sight is known only as the errors say (thickness and height are fixed "
                            "assumptions: mu x thickness is what the shadow measures)"})
    return out
