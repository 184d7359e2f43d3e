"""The diagnose loop: fit the current model, compare with the data, find what is missing, add it, compare again.

Everything here reads the dataset's frames and scenario only, never its truth: the source error in the report is
computed afterwards by :func:`reporting.truth_errors.score_diagnosis`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from estimator.diagnose.backend import (
    NON_COUNT_EFFECTS,
    SPECTRAL_EFFECTS,
    VARIANCE_EFFECTS,
    WALLS,
    CountFitter,
    FitTask,
    describe,
    progress,
    split_effects,
)
from estimator.diagnose.background_time import BackgroundTimeCheck, background_time_check
from estimator.diagnose.dispersion import fit_dispersion
from estimator.diagnose.explain import feature_of
from estimator.diagnose.features import Features, compute_features
from estimator.diagnose.motion import BREAKS as MOTION_BREAKS
from estimator.diagnose.motion import MotionCheck, MotionSearch
from estimator.diagnose.nuclide import NuclideChoice, identify_second_nuclide
from estimator.diagnose.residuals import (
    GoodnessOfFit,
    Trend,
    aggregate,
    goodness_of_fit,
    pearson,
    pose_penalty,
    segments,
    trend,
)
from estimator.diagnose.selection import Selection, forward_select, null_log10_p
from estimator.diagnose.threads import blas_threads
from estimator.diagnose.verdict import adequate, hotspots, misfit_text
from estimator.mle import SCREEN_MARGIN
from estimator.spectral import SpectralFit, SpectralModel
from radseek.dataset import Dataset

SPECTRAL_FEATURE = "spectral channel over time"
DISPERSION_FEATURE = "frame-to-frame scatter"


@dataclass
class ModelReport:
    """One fitted model with its comparison to the measurements."""

    effects: tuple[str, ...]  # count effects + spectral effects
    fit: Any
    gof: GoodnessOfFit  # per frame
    gof_segments: GoodnessOfFit  # per dwell / 1 s transit segment
    features: Features
    trends: dict[str, Trend]
    segment_labels: np.ndarray
    segment_pearson: np.ndarray
    residual_rms: float  # RMS of per-segment Pearson residuals (1 if the model is right)
    spectral: SpectralFit | None
    spectral_dev_per_dof: float
    sources: list[dict[str, float]]
    source_error_m: float | None  # vs the truth: filled by reporting.truth_errors.score_diagnosis, never here
    counts: np.ndarray  # (N,) observed total counts per frame
    effect_params: dict[str, tuple[float, float]] = field(default_factory=dict)


def sources_of(fit: Any) -> list[dict[str, float]]:
    v = fit.values
    out = [{"x": float(v["x"]), "y": float(v["y"]), "z": float(v.get("z", 0.0)), "cps_at_1m": float(v["cps_at_1m"])}]
    if "second_source.x" in v:
        out.append({"x": float(v["second_source.x"]), "y": float(v["second_source.y"]),
                    "z": float(v.get("second_source.z", 0.0)), "cps_at_1m": float(v["second_source.cps_at_1m"])})
    return out


def analyse(ds: Dataset, effects: tuple[str, ...], fit: Any, spectral: SpectralFit | None, n_bins: int = 8
            ) -> ModelReport:
    f = ds.frames
    n = f.total_counts.astype(float)
    mu = np.asarray(fit.expected, dtype=float)
    k = len(fit.free_names)
    disp = fit_dispersion(f, mu) if "over_dispersion" in effects else None
    rel_var = disp.rel_sd**2 if disp is not None else 0.0
    gof = goodness_of_fit(n, mu, k, penalty=pose_penalty(fit, n, mu), rel_var=rel_var)
    lab = segments(f, transit_s=1.0)
    sn, smu = aggregate(lab, n, mu)
    gof_seg = goodness_of_fit(sn, smu, k)  # per segment: what a smooth mean misfit leaves (no variance term)
    seg_p = pearson(sn, smu)
    src = sources_of(fit)
    feats = compute_features(f, ds.scenario, np.array([src[0]["x"], src[0]["y"], src[0]["z"]]), mu)
    trends = {}
    for name, values in feats.scalar_features().items():
        if name in ("x", "y"):
            continue
        if name.startswith("wall") and not np.any(values > 0):
            continue
        tr = trend(name, values, n, mu, n_bins=n_bins, log=name in ("count rate", "distance"),
                   zero_bin=name.startswith("wall"))
        if tr is not None:
            trends[name] = tr
    spec_dev = float("nan")
    if spectral is not None:
        spec_dev = spectral.deviance_per_dof if "gain_drift" in effects else spectral.deviance_per_dof_null
    params = {nm: (float(fit.values[nm]), float(fit.errors.get(nm, float("nan"))))
              for nm in fit.free_names if "." in nm}
    if "gain_drift" in effects and spectral is not None:
        params["gain_drift.percent_per_min"] = (spectral.percent_per_min, spectral.error)
    if disp is not None:
        params["over_dispersion.rel_sd"] = (disp.rel_sd, disp.error)
    return ModelReport(effects, fit, gof, gof_seg, feats, trends, lab, seg_p, float(np.sqrt(np.mean(seg_p**2))),
                       spectral, spec_dev, src, None, n, params)


def explained_feature(before: ModelReport, after: ModelReport, effect: str) -> str:
    """The residual feature whose trend the effect removed most (chi2 drop), with the expected one first."""
    if effect in SPECTRAL_EFFECTS:
        return SPECTRAL_FEATURE
    if effect in VARIANCE_EFFECTS:
        return DISPERSION_FEATURE
    drops = {}
    for name, tb in before.trends.items():
        ta = after.trends.get(name)
        if ta is not None:
            drops[name] = tb.chi2 - ta.chi2
    # position: the residual map (per-segment deviance)
    drops["position"] = (before.gof_segments.deviance - after.gof_segments.deviance) / 4.0
    if not drops:
        return feature_of(effect)
    best = max(drops, key=lambda k: drops[k])
    expected = [k for k in drops if k.startswith(feature_of(effect)) or
                (feature_of(effect) == "x" and k == "position")]
    exp_best = max(expected, key=lambda k: drops[k]) if expected else None
    # name the feature the physics predicts when it takes at least half of the largest improvement
    if exp_best is not None and drops[exp_best] > 0 and drops[exp_best] >= 0.5 * drops[best]:
        return exp_best
    return best if drops[best] > 0 else feature_of(effect)


def _fill_explains(ds: Dataset, fitter: CountFitter, sel: Selection, spectral: SpectralFit | None) -> None:
    """Which residual feature each candidate explains: compare its trends with the model it extends."""
    for step in sel.steps:
        base = step.base or fitter.fit(tuple(e for e in step.effects if e not in NON_COUNT_EFFECTS))
        ref = analyse(ds, step.effects, base, spectral)
        for c in step.candidates:
            if c.effect in SPECTRAL_EFFECTS:
                c.explains = SPECTRAL_FEATURE
            elif c.effect in VARIANCE_EFFECTS:
                c.explains = DISPERSION_FEATURE
            else:
                c.explains = explained_feature(ref, analyse(ds, (*step.effects, c.effect), c.fit, spectral), c.effect)


class LazySpectral:
    """The spectral fit (gain drift profiled), computed once on first use; ``compute`` may also run in a worker
    process, whose result is then stored in ``value``."""

    def __init__(self, model: SpectralModel, frames: Any, quiet: bool = False):
        self.model, self.frames, self.quiet = model, frames, quiet
        self.value: SpectralFit | None = None

    def compute(self) -> SpectralFit:
        return self.model.fit(self.frames)

    def __call__(self) -> SpectralFit:
        if self.value is None:
            progress("testing gain_drift (spectral model, 32 channels)", self.quiet)
            self.value = self.compute()
        return self.value


@dataclass
class Diagnosis:
    dataset: Dataset
    alpha: float
    current: ModelReport
    selection: Selection
    added: tuple[str, ...]  # --add effects (empty if none)
    after: ModelReport | None  # model with --add effects, else with the selected missing effects (or None)
    after_selection: Selection | None  # what is still missing after --add
    spectral: SpectralFit | None
    #: the verdict (``estimator.diagnose.verdict``): effects whose addition is supported and leaves an adequate
    #: fit; supported effects that still leave the fit inadequate; whether the final model misses something no
    #: candidate explains, and where its residual lives
    missing: list[str] = field(default_factory=list)
    partial: list[str] = field(default_factory=list)
    unexplained: bool = False
    hotspots: list[dict[str, Any]] = field(default_factory=list)
    #: effects the forward selection named that the final model no longer needs (``_backward``)
    dropped: list[str] = field(default_factory=list)
    #: each drop, with its test (``_backward``'s records: effect, lr, p_value, below_full)
    backward: list[dict[str, Any]] = field(default_factory=list)
    #: the model the verdict judged (``final``, or with the effects still missing after --add)
    final_report: ModelReport | None = None
    #: the second source's nuclide, when the final model has one (``estimator.diagnose.nuclide``)
    nuclide: NuclideChoice | None = None
    #: whether one source that moved mid-flight explains the counts better than several named effects
    #: (``estimator.diagnose.motion``; checked when two or more count effects were named)
    motion: MotionCheck | None = None
    #: whether a background changing in time explains the counts better than the named effects
    #: (``estimator.diagnose.background_time``; checked when a count effect was named)
    background_time: BackgroundTimeCheck | None = None

    @property
    def off_list(self) -> MotionCheck | BackgroundTimeCheck | None:
        """The off-list explanation that beat the named effects (the stronger, if both did), or None."""
        hits = [c for c in (self.motion, self.background_time) if c is not None and c.significant]
        return max(hits, key=lambda c: c.aic_gap - c.threshold) if hits else None

    @property
    def final(self) -> ModelReport:
        """The model the verdict is about: with --add effects, else with the selected effects, else the start."""
        return self.after if self.after is not None else self.current


def diagnose(ds: Dataset, model: tuple[str, ...] = (), add: tuple[str, ...] = (), alpha: float = 0.01,
             n_starts: int = 8, seed: int = 0, quiet: bool = False, jobs: int = 1, saved: Path | None = None
             ) -> Diagnosis:
    """The whole loop (see the module docstring); BLAS runs single-threaded inside (``threads``). ``saved``: a
    file of this dataset's fits and selections (``CountFitter.save``), reused when it matches and rewritten after:
    ``--add`` after a first run refits nothing it has already fitted."""
    with blas_threads(1):
        fitter = CountFitter(ds.scenario, ds.frames, n_starts=n_starts, seed=seed, quiet=quiet, jobs=jobs)
        if saved is not None and saved.exists():
            reused = fitter.load(saved)
            progress(f"reusing the fits and selections saved in {saved}" if reused else
                     f"{saved} holds another dataset's or setting's fits: fitting anew", quiet)
        d = _diagnose(ds, fitter, model, add, alpha, quiet)
        if saved is not None:
            fitter.save(saved)
        return d


def _diagnose(ds: Dataset, fitter: CountFitter, model: tuple[str, ...], add: tuple[str, ...], alpha: float,
              quiet: bool) -> Diagnosis:
    count, spec = split_effects(model)
    add_count, add_spec = split_effects(add)
    progress(f"{ds.name}: {len(ds.frames)} frames; fitting {describe((*count, *spec))}",
             quiet)
    sm = SpectralModel(ds.scenario.channel_edges_keV)
    spectral_fit = LazySpectral(sm, ds.frames, quiet)
    spectral_fit.value = fitter.spectral

    base = fitter.fit(count)
    spectral = spectral_fit() if "gain_drift" in (*spec, *add_spec) else None
    current = analyse(ds, (*count, *spec), base, spectral)
    sel = forward_select(fitter, spectral_fit, (*count, *spec), alpha=alpha, quiet=quiet)
    spectral = spectral_fit.value or spectral
    if spectral is not None:
        current = analyse(ds, (*count, *spec), base, spectral)
    _fill_explains(ds, fitter, sel, spectral)
    added = tuple(add)
    after = None
    after_sel = None
    target = list(dict.fromkeys((*count, *spec, *add_count, *add_spec))) if add else [*count, *spec, *sel.missing]
    dropped: list[str] = []
    backward: list[dict[str, Any]] = []
    reduced = None
    if not add and len(sel.missing) >= 2:
        dropped, reduced, backward = _backward(fitter, sel, (*count, *spec), alpha, quiet)
        target = [e for e in target if e not in dropped]
    if add or sel.missing:
        tc, ts = split_effects(target)
        progress(f"refitting with {describe((*tc, *ts))}", quiet)
        # start from the selection's fits of these effects (an unmapped wall's placement among them)
        init = dict(base.values)
        for st in sel.steps:
            if st.chosen and st.chosen in tc:
                init.update(st.candidates[0].fit.values)
        after_fit = reduced if reduced is not None else fitter.fit(tc, init=init)
        after = analyse(ds, (*tc, *ts), after_fit, spectral)
        if add:
            after_sel = forward_select(fitter, spectral_fit, (*tc, *ts), alpha=alpha, quiet=quiet)
            _fill_explains(ds, fitter, after_sel, spectral_fit.value or spectral)
    fitter.spectral = spectral_fit.value
    d = Diagnosis(ds, alpha, current, sel, added, after, after_sel, spectral)
    d.dropped = dropped
    d.backward = backward
    named = [e for e in (after_sel.missing if add and after_sel is not None else sel.missing) if e not in dropped]
    final = d.final
    if named and final is not after:  # --add with more still missing: judge the model with those in too
        tc, ts = split_effects((*final.effects, *named))
        final = analyse(ds, (*tc, *ts), fitter.fit(tc, init=dict(final.fit.values)), spectral)
    if "second_source" in final.effects and spectral is not None:
        # the spectral verdict with the second source's own spectrum in (its share per frame from the count model)
        final = analyse(ds, final.effects, final.fit, second_source_spectral(ds, final))
    ok = adequate(final, ds.frames)
    n_count = len([e for e in named if e not in NON_COUNT_EFFECTS])
    if ok and n_count >= 1 and final.fit.model.channels is None:
        # an adequate fit that needed count effects: do they stand in for off-list physics?
        start = fitter.model(count)
        checks = {"background_time": partial(background_time_check, start, fitter.fit_frames, final.fit,
                                             seed=fitter.seed)}
        search = MotionSearch(start, fitter.fit_frames, final.fit, fitter.seed) if n_count >= 2 else None
        progress("checking whether a background changing in time explains the counts better"
                 + (f", and one moved source ({len(MOTION_BREAKS)} break times)" if search else ""), quiet)

        def run(calls: dict[str, Any]) -> dict[str, Any]:  # independent fits side by side, with --jobs
            return fitter.fit_many([], calls, label="off-list checks")[1]

        # the changing background and the moved source's first looks are independent fits: one batch
        looks = run({**checks, **(search.first_looks() if search else {})})
        d.background_time = looks.pop("background_time")
        if search is not None:
            looks.update(run(search.next_looks(looks)))
            d.motion = search.result(looks)
        ok = d.off_list is None
    d.missing, d.partial = (_report_names(named), []) if ok else ([], _report_names(named))
    d.unexplained = not ok
    d.hotspots = hotspots(final, ds.scenario.channel_edges_keV)
    hit = d.off_list
    if hit is not None:
        d.hotspots.insert(0, {"kind": "motion" if hit is d.motion else "background_time",
                              "z": round(math.sqrt(max(hit.aic_gap, 0.0)), 1), "where": hit.text(), **hit.to_json()})
    d.final_report = final
    if "second_source" in final.effects:
        d.nuclide = second_nuclide(ds, final)
        progress(f"second source: {d.nuclide.note}", quiet)
    if d.unexplained:
        why = d.off_list.text() if d.off_list is not None else misfit_text(final, ds.frames)
        progress(f"the final model misses something none of the candidates explains ({why})", quiet)
    return d


#: -log L by which a drop fit may beat the fit with every effect before the message says that fit stopped short (a
#: tenth of the 0.5 of a 1-sigma step is MIGRAD's own tolerance scale; 0.5 is well beyond it)
BELOW_FULL_NOTE = 0.5


#: LR beyond its threshold by which a named effect's drop is decisive: its drop model is not fitted again in a later
#: round of the backward check (twice the screen's margin between basins, :data:`estimator.mle.SCREEN_MARGIN`)
DECISIVE_LR = 2.0 * SCREEN_MARGIN


def _backward(fitter: CountFitter, sel: Selection, start: tuple[str, ...], alpha: float, quiet: bool
              ) -> tuple[list[str], Any, list[dict[str, Any]]]:
    """Effects the forward selection named that the final model no longer needs, and the fit of the model left.

    Each named count effect is dropped in turn from the model with all of them (every placement free), and kept
    only if the drop is significant at alpha / (effects named) by its own null (an effect named early can be
    taken over by one named later: a distance trend left by one wall, explained by a second). The least needed
    goes, and the test is repeated on the model left (a second source named before the wall whose shadow it
    stood in for, and a second wall, both went on a one-wall flight: the second source kept 33 of its 2,900
    counts once the free wall moved). Returns (the effects to drop, the fit without them (None if none), a record
    of each drop: ``effect``, ``lr``, ``p_value`` and ``below_full``).

    The model with every effect nests each drop's, so at its optimum no drop fits better; a drop fit that does
    shows that the fit with every effect stopped in a worse minimum (three walls' shadows fitted with two, a second
    source and anisotropy make several). That fit is then fitted once more from the drop's basin, the dropped effect
    as the full fit had it, and the drops again from there if it went lower. A drop still below it (by
    ``below_full`` in -log L) has LR 0: the effect is dropped, as the best fit found does without it, and the
    message says why: with several minima the answer can depend on the search.

    A drop that an earlier round found decisive is not fitted again. Dropping g from the model C changes an effect
    e's test by no more than g's own: the minima nest, so LR(e | C - g) >= LR(e | C) - LR(g | C). An effect whose
    LR, less every later drop's, still exceeds its threshold by :data:`DECISIVE_LR` (a refit of the full model only
    raises it) is kept without its drop fit: a two-wall flight's drop of its second wall (LR 1,100 against ~13) took
    12-17 s each round, three rounds."""
    named = [e for e in sel.missing if e not in NON_COUNT_EFFECTS]
    if len(named) < 2:
        return [], None, []
    count = split_effects((*start, *sel.missing))[0]
    init: dict[str, float] = {}
    for st in sel.steps:
        if st.chosen and st.chosen not in NON_COUNT_EFFECTS:  # (over_dispersion's or a spectral fit has no values)
            init.update(st.candidates[0].fit.values)
    full = fitter.fit(count, init=init)
    thr = math.log10(alpha / len(named))
    dropped: list[str] = []
    records: list[dict[str, Any]] = []
    refitted = False
    sure: dict[str, float] = {}  # a lower bound on a named effect's LR in the current model, from an earlier round

    def log10_p(e: str, lr: float, k: int) -> float:
        looks = next((getattr(c.fit, "wall_looks", None) for st in sel.steps for c in st.candidates
                      if c.effect == e), None)
        return null_log10_p(e, lr, k, fitter.scenario, fitter.frames, looks)[0]

    while len(named) >= 2:
        worst: tuple[float, str, Any, float] | None = None
        # the second wall goes first
        drops = [e for e in named if not (e == "unmapped_wall" and "unmapped_wall_2" in count)]
        kept = [e for e in drops if e in sure and log10_p(e, sure[e] - DECISIVE_LR, _n_new(full, e)) < thr]
        if kept:
            progress("kept without a new drop fit (decisive in an earlier round): " + ", ".join(
                f"{e} (LR >= {sure[e]:.0f})" for e in kept), quiet)
        drops = [e for e in drops if e not in kept]
        if not drops:
            break
        # from the full model's optimum (the other effects' placements as they are there): a reduced fit that
        # fell into another basin would make every effect look needed. The drops are independent fits, run as
        # one batch (in parallel with --jobs): with two walls, a second source and every placement free, each
        # took 45-90 s of a three-slab flight's call
        reds, _ = fitter.fit_many([FitTask(tuple(x for x in count if x != e), dict(full.values),
                                           label=f"{describe(count)} without {e}", cache=False) for e in drops],
                                  label="backward check: drop fits")
        lrs = {e: max(2.0 * (red.nll - full.nll), 0.0) for e, red in zip(drops, reds, strict=True)}
        below_e, below_red = min(zip(drops, reds, strict=True), key=lambda t: t[1].nll)
        if not refitted and below_red.nll < full.nll - BELOW_FULL_NOTE:
            # the fit with every effect stopped in a worse minimum than a drop's: fitted once more from that drop's
            # basin (the dropped effect as the full fit had it), and the drops again from there if it went lower
            refitted = True
            again = fitter.fit(count, init={**full.values, **below_red.values}, n_starts=1, cache=False,
                               label=f"{describe(count)} again, from the fit without {below_e}")
            progress(f"the fit with every effect was {full.nll - below_red.nll:.1f} above the fit without {below_e} "
                     f"in -log L; fitted again from there: {full.nll - again.nll:+.1f}", quiet)
            if again.nll < full.nll:
                # a lower full fit only raises each drop's LR: this round's stand as bounds
                sure.update(lrs)
                full = again
                continue
        for e, red in zip(drops, reds, strict=True):
            lp = log10_p(e, lrs[e], len(set(full.free_names) - set(red.free_names)))
            if lp > thr and (worst is None or lp > worst[0]):
                worst = (lp, e, red, lrs[e])
        if worst is None:
            break
        # LR(e | C - g) >= LR(e | C) - LR(g | C): the bounds for the model left
        sure = {e: lr - worst[3] for e, lr in {**sure, **lrs}.items() if e in named and e != worst[1]}
        below = max(full.nll - worst[2].nll, 0.0)
        progress(f"{worst[1]} is no longer needed once the other effects are in (p = {10 ** worst[0]:.2g}): "
                 "dropped" + (f" (the fit without it is {below:.1f} lower in -log L than the fit with every effect, "
                              "which had stopped in a worse minimum: with several minima the answer can depend on "
                              "the search)" if below > BELOW_FULL_NOTE else ""), quiet)
        records.append({"effect": worst[1], "lr": round(worst[3], 3), "p_value": float(10 ** worst[0]),
                        "below_full": round(below, 3)})
        dropped.append(worst[1])
        named.remove(worst[1])
        count = tuple(x for x in count if x != worst[1])
        full = worst[2]
    return dropped, (full if dropped else None), records


def _n_new(full: Any, effect: str) -> int:
    """Free parameters of ``effect`` in ``full`` (a fit): ``"<effect>.<key>"``."""
    return len([n for n in full.free_names if n.startswith(f"{effect}.")])


def _source_counts(ds: Dataset, rep: ModelReport) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame, the final fit's expected counts of the primary source, of the second source and of the
    background."""
    model, th = rep.fit.model, dict(rep.fit.values)
    no2 = {**th, "second_source.cps_at_1m": 0.0}
    mu = model.expected_counts(th, ds.frames)
    mu1 = model.expected_counts(no2, ds.frames)
    bg = model.expected_counts({**no2, "cps_at_1m": 0.0}, ds.frames)
    return np.maximum(mu1 - bg, 0.0), np.maximum(mu - mu1, 0.0), bg


def second_source_spectral(ds: Dataset, rep: ModelReport) -> SpectralFit:
    """The spectral fit with the second source's spectrum as a component of its own, in the ratio to the
    primary's counts the count model gives each frame (``SpectralModel.fit(second=...)``): drift free when the
    model has ``gain_drift``."""
    first, other, _ = _source_counts(ds, rep)
    return SpectralModel(ds.scenario.channel_edges_keV).fit(ds.frames, drift="gain_drift" in rep.effects,
                                                            second=(first, other))


def second_nuclide(ds: Dataset, rep: ModelReport) -> NuclideChoice:
    """The second source's nuclide from the flight's spectra (``nuclide``), with the count model's expected
    counts of each source and the background split out of the final fit."""
    first, other, bg = _source_counts(ds, rep)
    return identify_second_nuclide(ds.frames, ds.scenario.channel_edges_keV, ds.scenario.nuclide or "Cs-137",
                                   first, other, bg)


def _report_names(effects: list[str]) -> list[str]:
    """Effect names as the dataset spec has them (a second unmapped wall is an ``unmapped_wall`` too)."""
    return list(dict.fromkeys("unmapped_wall" if e in WALLS else e for e in effects))
