"""Which effect is missing: forward selection over the effect vocabulary by likelihood-ratio evidence.

At each step every effect not yet in the model is added in turn to the *current* model (effects interact,
so candidates are tested conditional on what is already in), each extended model is fitted by Poisson
maximum likelihood with pose uncertainty, and the likelihood-ratio statistic LR = 2 (nll_current - nll_ext)
is turned into a p-value with the null distribution that is right for that effect:

- ``dead_time``, ``wall_attenuation``, ``air_attenuation``: one parameter on its boundary (>= 0) under the null,
  so LR ~ 1/2 chi2_0 + 1/2 chi2_1 (chi-bar-square, Self & Liang 1987): p = 1/2 P(chi2_1 > LR).
- ``anisotropy``: the fraction is on its boundary and the half-angle is not identified when the fraction is 0
  (Davies' problem). Conservative: Bonferroni over the ~``ANISO_LOOKS`` distinguishable half-angles
  (5-90 deg at the 4 deg edge width -> 10), p = min(1, 10 * 1/2 P(chi2_1 > LR)).
- ``second_source``: the strength is on its boundary and the location is not identified under the null
  (Davies). Conservative: Bonferroni over the number of distinguishable locations, the search area divided
  by the squared median detector height above the floor (the width of one source's count-rate hill),
  p = min(1, M * 1/2 P(chi2_1 > LR)).
- ``unmapped_wall`` (and a second one, ``unmapped_wall_2``, offered once the first is in): mu on its boundary
  and the slab's ends not identified under the null (Davies). Conservative: Bonferroni over the placements its
  shadow screen scored (``estimator.diagnose.shadow``), p = min(1, M * 1/2 P(chi2_1 > LR)).
- ``background_gradient``, ``pose_drift``: two unbounded parameters, chi2_2. ``gain_drift``: chi2_1 (spectral
  likelihood, ``estimator.spectral``), on LR divided by the spectral fit's over-dispersion when it exceeds 1.
- ``over_dispersion``: frame-to-frame extra-Poisson variance, tested on pairs of consecutive frames so that a
  wrong mean cannot fake it (``estimator.diagnose.dispersion``); r >= 0 on its boundary: 1/2 chi2_0 + 1/2 chi2_1.
  Every count-model LR is divided by its dispersion factor phi (quasi-likelihood; measured at each step whether or
  not over_dispersion is named), so
  extra-Poisson variance is not a reason to name a geometry effect.

Several candidates are tested per step, so a candidate is significant when p < alpha / (number of candidates)
(Bonferroni). Candidates are ranked by this p-value (ties by delta-AIC = AIC_ext - AIC_current, negative
favours the effect); the best significant one is added and the search repeats, so a second missing effect is
still found after the first is in. When no candidate is significant the model is called adequate.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from estimator.diagnose.backend import (
    NON_COUNT_EFFECTS,
    SPECTRAL_EFFECTS,
    VARIANCE_EFFECTS,
    VOCABULARY,
    WALLS,
    CountFitter,
    FitTask,
    progress,
)
from estimator.diagnose.dispersion import fit_dispersion
from estimator.diagnose.residuals import aggregate, group_mean, pearson, segments
from radseek.dataset import Frames, Scenario

ANISO_LOOKS = 10
#: an unmapped wall's placement parameters (held while a step tests other effects)
PLACEMENT = ("r", "phi_deg", "tilt_deg", "length")
BOUNDARY_ONE = ("dead_time", "wall_attenuation", "air_attenuation", "over_dispersion")


def second_source_looks(scenario: Scenario, frames: Frames) -> int:
    """Distinguishable second-source locations: search area / (median height above the floor)^2."""
    area = float(np.prod(np.maximum(scenario.bounds_max[:2] - scenario.bounds_min[:2], 0.1)))
    h = max(float(np.median(frames.z)) - scenario.source_z, 0.5)
    return int(np.clip(math.ceil(area / h**2), 4, 5000))


def chi2_logsf(x: float, k: int) -> float:
    """log P(chi2_k > x), finite far in the tail (scipy underflows to -inf beyond x ~ 1500)."""
    v = float(stats.chi2.logsf(x, k))
    if math.isfinite(v):
        return v
    # leading term of the upper incomplete gamma function's asymptotic series
    return -x / 2 + (k / 2 - 1) * math.log(x / 2) - math.lgamma(k / 2)


def null_log10_p(effect: str, lr: float, k: int, scenario: Scenario, frames: Frames, looks: int | None = None
                 ) -> tuple[float, str]:
    """log10 p-value of LR under the effect's null, and the null's name (``looks``: placements an unmapped
    wall's screen scored)."""
    lr = max(float(lr), 0.0)
    ln10 = math.log(10)
    if effect in WALLS:
        m = max(int(looks or 1), 1)
        name = (f"Bonferroni over {m} wall placements x (1/2 chi2_0 + 1/2 chi2_1) (Davies: the slab's ends are not "
                "identified under the null)")
        if lr <= 0:
            return 0.0, name
        return min(0.0, (math.log(0.5 * m) + chi2_logsf(lr, 1)) / ln10), name
    if effect in BOUNDARY_ONE:
        if lr <= 0:
            return 0.0, "1/2 chi2_0 + 1/2 chi2_1 (parameter on its boundary)"
        return (math.log(0.5) + chi2_logsf(lr, 1)) / ln10, "1/2 chi2_0 + 1/2 chi2_1 (parameter on its boundary)"
    if effect in ("anisotropy", "second_source"):
        looks = ANISO_LOOKS if effect == "anisotropy" else second_source_looks(scenario, frames)
        name = (f"Bonferroni over {looks} {'half-angles' if effect == 'anisotropy' else 'locations'} x "
                "(1/2 chi2_0 + 1/2 chi2_1) (Davies: nuisance not identified under the null)")
        if lr <= 0:
            return 0.0, name
        return min(0.0, (math.log(0.5 * looks) + chi2_logsf(lr, 1)) / ln10), name
    dof = max(k, 1)
    return chi2_logsf(lr, dof) / ln10, f"chi2_{dof}"


@dataclass
class Candidate:
    effect: str
    lr: float
    n_params: int
    delta_aic: float
    log10_p: float
    null: str
    params: dict[str, float]
    errors: dict[str, float]
    significant: bool = False
    threshold: float = 0.0  # alpha / number of candidates
    explains: str = ""  # the residual feature whose trend this effect removes (filled by the runner)
    fit: Any = field(default=None, repr=False)

    @property
    def p_value(self) -> float:
        return 10.0**self.log10_p

    def to_json(self) -> dict[str, Any]:
        return {
            "effect": self.effect,
            "delta_aic": round(float(self.delta_aic), 3),
            "lr": round(float(self.lr), 3),
            "n_params": self.n_params,
            "p_value": float(self.p_value),
            "log10_p": round(float(self.log10_p), 3),
            "null_distribution": self.null,
            "significant": bool(self.significant),
            "explains": self.explains,
            "params": {k: float(v) for k, v in self.params.items()},
            "errors": {k: float(v) for k, v in self.errors.items()},
        }


@dataclass
class Step:
    effects: tuple[str, ...]  # the model the candidates extend
    candidates: list[Candidate]  # ranked, best first
    chosen: str | None
    #: the fit of ``effects`` the candidates were tested against (None in a selection saved before it was kept)
    base: Any = field(default=None, repr=False)


@dataclass
class Selection:
    steps: list[Step]
    missing: list[str]
    alpha: float

    @property
    def first(self) -> list[Candidate]:
        return self.steps[0].candidates if self.steps else []


def excess_seed(frames: Frames, expected: np.ndarray, scenario: Scenario, exclude_xy: np.ndarray | None = None
                ) -> dict[str, float]:
    """Start values for a second source at the segment with the largest count excess over the current fit."""
    lab = segments(frames, transit_s=1.0)
    n, mu, dur = aggregate(lab, frames.total_counts, expected, frames.duration)
    x, y, z = (group_mean(lab, v) for v in (frames.x, frames.y, frames.z))
    score = pearson(n, mu)
    if exclude_xy is not None:
        far = np.hypot(x - exclude_xy[0], y - exclude_xy[1]) > 1.0
        score = np.where(far, score, -np.inf) if far.any() else score
    i = int(np.argmax(score))
    h = max(z[i] - scenario.source_z, 0.3)
    lo, hi = scenario.bounds_min, scenario.bounds_max
    return {
        "second_source.x": float(np.clip(x[i], lo[0], hi[0])),
        "second_source.y": float(np.clip(y[i], lo[1], hi[1])),
        "second_source.cps_at_1m": float(max((n[i] - mu[i]) / dur[i], 1.0) * h**2),
    }


def _new_params(ext: Any, cur: Any) -> tuple[dict[str, float], dict[str, float], int]:
    names = [nm for nm in ext.free_names if nm not in set(cur.free_names)]
    return ({nm: float(ext.values[nm]) for nm in names}, {nm: float(ext.errors.get(nm, float("nan"))) for nm in names},
            len(names))


def forward_select(fitter: CountFitter, spectral_fit: Callable[[], Any], start: tuple[str, ...],
                   alpha: float = 0.01, max_steps: int = 4, quiet: bool = False) -> Selection:
    """Forward selection from the effects ``start`` (count effects plus possibly ``gain_drift``).

    ``spectral_fit()`` returns the ``estimator.spectral.SpectralFit`` (with drift profiled), computed lazily.
    A selection the fitter has already run (from the same start, alpha and steps) is returned as it was.
    """
    key = (tuple(start), alpha, max_steps)
    if key not in fitter.selections:
        try:
            fitter.selections[key] = _forward_select(fitter, spectral_fit, start, alpha, max_steps, quiet)
        finally:
            fitter.wall_threshold = None  # outside a selection an unmapped wall is always fitted in full
            fitter.hold = ()
    return fitter.selections[key]


def _forward_select(fitter: CountFitter, spectral_fit: Callable[[], Any], start: tuple[str, ...], alpha: float,
                    max_steps: int, quiet: bool) -> Selection:
    scenario, frames = fitter.scenario, fitter.frames
    count = tuple(e for e in start if e not in NON_COUNT_EFFECTS)
    spec = tuple(e for e in start if e in NON_COUNT_EFFECTS)
    steps: list[Step] = []
    missing: list[str] = []
    chosen_fit: Any = None
    for _ in range(max_steps):
        # the model with the effect just named is that candidate's fit, the placements it held still held: the
        # next step's candidates hold them too, so it is the baseline they extend. Fitted from scratch, the walls
        # were screened and fitted again from a worse optimum (nll 10.6 higher on a lattice flight), and fitted
        # from there with every placement free, one fit took 55 s of a 190 s call; the model with every
        # placement free is fitted once, at the end (``runner``)
        fitter.hold = ()
        if chosen_fit is None:
            cur = fitter.fit(count)
        elif getattr(chosen_fit, "screened_only", False):
            cur = fitter.fit(count, init=dict(chosen_fit.values), n_starts=1)
        else:
            cur = chosen_fit
        todo = [e for e in VOCABULARY if e not in count and e not in spec]
        # over-dispersion in the model: count-model evidence is scaled by its dispersion factor (quasi-likelihood)
        # quasi-likelihood: every count-model LR is divided by the extra-Poisson variance measured on pairs of
        # consecutive frames (smooth misfits of the mean cancel from a pair), whether or not over_dispersion is
        # named: over-dispersed counts are not a reason to name a geometry effect (Co-60 nulls with r ~ 0.06 named
        # air_attenuation otherwise)
        phi = max(fit_dispersion(fitter.fit_frames, cur.expected).phi, 1.0)
        if not scenario.walls:
            todo = [e for e in todo if e != "wall_attenuation"]
        if "unmapped_wall" not in count:
            todo = [e for e in todo if e != "unmapped_wall_2"]
        if not todo:
            break
        cands: list[Candidate] = []
        # every count-model fit of this step (and the spectral fit, when still to do) as one batch: run in
        # parallel with --jobs, with a progress bar
        tasks: list[FitTask] = []
        owner: list[str] = []
        for e in todo:
            if e in NON_COUNT_EFFECTS:
                continue
            # start from the current optimum (the effect at its default); a second source starts at the largest
            # residual excess and at its best grid cell (estimator.mle.second_source_starts), since its location
            # is not identified by the current fit: one fit, whose screen searches only the better basin in full;
            # the anisotropy also starts from a wide cone
            init = dict(cur.values)
            label = f"{'+'.join(count) or 'baseline'} + {e}"
            if e == "second_source":
                seed = dict(init, **excess_seed(frames, cur.expected, scenario,
                                                np.array([cur.values["x"], cur.values["y"]])))
                tasks.append(FitTask((*count, e), seed, 2, f"{label} (excess and grid starts)", second_grid=True))
                owner.append(e)
            else:
                tasks.append(FitTask((*count, e), init, 1, label))
                owner.append(e)
            if e == "anisotropy":
                tasks.append(FitTask((*count, e), dict(init, **{"anisotropy.half_angle_deg": 60.0}), 1,
                                     f"{e} (wide cone start)", cache=False))
                owner.append(e)
            if e == "wall_attenuation":
                # a wall the model lacks pushes the fitted source away from it, and from there a wall cannot
                # help (mu -> 0, LR 0: seen on an independent L-shaped wall): also start from the source grid
                tasks.append(FitTask((*count, e), {k: v for k, v in init.items() if k not in ("x", "y", "cps_at_1m")},
                                     3, f"{label} (grid starts)", cache=False))
                owner.append(e)
        fitter.wall_threshold = alpha / len(todo)
        # the placements of the walls and of a second source already in the model are held while other effects
        # are tested (their LR a lower bound): a step on a model with a second source and two walls fitted
        # seventeen parameters per candidate, 5-30 s each on 900 frames
        fitter.hold = (*(f"{w}.{k}" for w in WALLS if w in count for k in PLACEMENT),
                       *(("second_source.x", "second_source.y") if "second_source" in count else ()))
        side = {}
        if "gain_drift" in todo and getattr(spectral_fit, "value", None) is None and hasattr(spectral_fit, "compute"):
            side["spectral"] = spectral_fit.compute
        fits, side_out = fitter.fit_many(tasks, side, label=f"step {len(steps) + 1}: candidate fits")
        if "spectral" in side_out:
            spectral_fit.value = side_out["spectral"]
        best: dict[str, Any] = {}
        for e, r in zip(owner, fits, strict=True):
            if e not in best or r.nll < best[e].nll:
                best[e] = r
        for e in todo:
            if e in SPECTRAL_EFFECTS:
                sf = spectral_fit()
                lr_q = sf.lr_scaled  # quasi-likelihood: scaled by the no-drift fit's over-dispersion
                lp, null = null_log10_p(e, lr_q, 1, scenario, frames)
                if sf.dispersion > 1:
                    null += f" on LR / {sf.dispersion:.2f} (spectral over-dispersion)"
                cands.append(Candidate(e, lr_q, 1, 2 - lr_q, lp, null, {"gain_drift.percent_per_min":
                                       sf.percent_per_min}, {"gain_drift.percent_per_min": sf.error}, fit=sf))
                continue
            if e in VARIANCE_EFFECTS:
                disp = fit_dispersion(fitter.fit_frames, cur.expected)
                lp, null = null_log10_p(e, disp.lr, 1, scenario, frames)
                null += f" (pairs of consecutive frames, {disp.n_pairs} pairs)"
                cands.append(Candidate(e, disp.lr, 1, 2 - disp.lr, lp, null, {"over_dispersion.rel_sd": disp.rel_sd},
                                       {"over_dispersion.rel_sd": disp.error}, fit=disp))
                continue
            ext = best[e]
            lr = max(2.0 * (cur.nll - ext.nll), 0.0) / phi
            params, errors, k = _new_params(ext, cur)
            lp, null = null_log10_p(e, lr, k, scenario, frames, getattr(ext, "wall_looks", None))
            if phi > 1.005:
                null += f" on LR / {phi:.3g} (over-dispersion)"
            if getattr(ext, "screened_only", False):
                null += "; LR from the shadow screen (source held), a lower bound: too small to fit in full"
            cands.append(Candidate(e, lr, k, 2 * k - lr, lp, null, params, errors, fit=ext))
        thr = alpha / len(cands)
        for c in cands:
            c.threshold = thr
            c.significant = c.log10_p < math.log10(thr)
        cands.sort(key=lambda c: (c.log10_p, c.delta_aic))
        chosen = cands[0].effect if cands and cands[0].significant else None
        steps.append(Step((*count, *spec), cands, chosen, cur))
        if chosen is None:
            break
        missing.append(chosen)
        if chosen not in NON_COUNT_EFFECTS:
            chosen_fit = cands[0].fit
        progress(f"step {len(steps)}: {chosen} is missing (p = {cands[0].p_value:.2g} < {thr:.2g}); searching on",
                 quiet)
        if chosen in NON_COUNT_EFFECTS:
            spec = tuple(e for e in VOCABULARY if e in (*spec, chosen))
        else:
            count = tuple(e for e in VOCABULARY if e in (*count, chosen))
    fitter.hold = ()
    return Selection(steps, missing, alpha)
