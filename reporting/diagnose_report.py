"""The diagnose report: text for people, JSON for machines."""

from __future__ import annotations

import json
import math
from typing import Any

from estimator.diagnose.explain import physics
from estimator.diagnose.features import unit_of
from estimator.diagnose.residuals import describe_trend
from estimator.diagnose.runner import BELOW_FULL_NOTE, Diagnosis, ModelReport
from estimator.diagnose.selection import Selection
from estimator.diagnose.verdict import misfit_text, source_reading, unmapped_walls


def model_name(effects: tuple[str, ...] | list[str]) -> str:
    return "baseline (sources + constant background)" + "".join(f" + {e}" for e in effects)


def _fmt(v: float, e: float | None = None) -> str:
    s = f"{v:.4g}"
    if e is not None and math.isfinite(e):
        s += f" +- {e:.2g}"
    return s


def _sources_text(rep: ModelReport) -> list[str]:
    out = []
    errs = rep.fit.errors
    for i, s in enumerate(rep.sources):
        pre = "" if i == 0 else "second_source."
        out.append(
            f"  source {i + 1}: x {_fmt(s['x'], errs.get(pre + 'x'))} m, y {_fmt(s['y'], errs.get(pre + 'y'))} m, "
            f"z {s['z']:.2f} m, cps_at_1m {_fmt(s['cps_at_1m'], errs.get(pre + 'cps_at_1m'))}")
        if (plain := source_reading(s["cps_at_1m"], errs.get(pre + "cps_at_1m"))) is not None:
            out.append(f"    {plain}")
    bg = rep.fit.values.get("background_cps")
    if bg is not None:
        out.append(f"  background {_fmt(bg, errs.get('background_cps'))} cps")
    for k, (v, e) in rep.effect_params.items():
        if not k.startswith("second_source."):
            out.append(f"  {k} = {_fmt(v, e)}")
    if rep.source_error_m is not None:
        out.append(f"  source error (vs truth.json, reporting only): {rep.source_error_m:.3f} m")
    return out


def _gof_text(rep: ModelReport) -> list[str]:
    g = rep.gof
    out = [f"  deviance/dof {g.deviance_per_dof:.3f} (if the model were right: {g.expected_per_dof:.3f} +- "
           f"{g.sd_per_dof:.3f}, low-count corrected), p = {g.p_value:.3g}",
           f"  per-segment residual RMS {rep.residual_rms:.2f} (dwells and 1 s of transit; 1 if the model is right)"]
    if rep.spectral is not None and math.isfinite(rep.spectral_dev_per_dof):
        out.append(f"  spectral (32-channel) deviance/dof {rep.spectral_dev_per_dof:.3f}")
    return out


def _trends_text(rep: ModelReport, alpha: float) -> list[str]:
    lines = []
    order = sorted(rep.trends.values(), key=lambda t: t.p_value)
    for t in order:
        lines.append("  - " + describe_trend(t, unit_of(t.feature), alpha))
    g = rep.gof_segments
    lines.append(f"  - residual map (per segment): deviance {g.deviance:.1f} over {g.dof} dof, p = {g.p_value:.3g}")
    if rep.spectral is not None:
        sp = rep.spectral
        lines.append(f"  - spectral channel over time: gain drift {sp.percent_per_min:+.4f} +- {sp.error:.2g} %/min, "
                     f"LR {sp.lr:.1f} (p = {sp.p_value:.3g})")
    return lines


def _selection_text(sel: Selection) -> list[str]:
    lines = []
    for i, st in enumerate(sel.steps, 1):
        lines.append(f"  step {i}, extending {model_name(st.effects)} "
                     f"(significant if p < alpha/{len(st.candidates)} = {sel.alpha / max(len(st.candidates), 1):.2g}):")
        lines.append(f"    {'effect':20s} {'LR':>9s} {'dAIC':>9s} {'p':>9s}  {'explains':26s} fitted parameters")
        for c in st.candidates:
            ps = ", ".join(f"{k.split('.', 1)[1]} {_fmt(v, c.errors.get(k))}" for k, v in c.params.items())
            mark = "*" if c.significant else " "
            lines.append(f"  {mark} {c.effect:20s} {c.lr:9.1f} {c.delta_aic:9.1f} {c.p_value:9.2g}  "
                         f"{c.explains[:26]:26s} {ps}")
        if st.chosen:
            c = st.candidates[0]
            lines.append(f"    => {st.chosen} is missing ({c.null}; p = {c.p_value:.2g}). It removes the residual "
                         f"trend with {c.explains}.")
        else:
            lines.append("    => no candidate is significant: this model is adequate for these data.")
    return lines


def text_report(d: Diagnosis, plots: list[str] | None = None) -> str:
    ds = d.dataset
    f = ds.frames
    final = d.after if d.added and d.after is not None else d.current
    lines = [f"radseek diagnose {ds.name}: {len(f)} frames over {f.t[-1] - f.t[0] + f.duration[0]:.0f} s, "
             f"{int(f.total_counts.sum())} counts; alpha {d.alpha}", ""]
    lines.append(f"1. Fit of {model_name(d.current.effects)} (Poisson maximum likelihood, multi-start, "
                 "per-dwell pose offsets as nuisances)")
    lines += _sources_text(d.current)
    lines += ["", "2. Comparison with the measurements"] + _gof_text(d.current)
    lines += ["", "3. Where it fails (residuals binned against each feature; plots in the output folder)"]
    lines += _trends_text(d.current, d.alpha)
    lines += ["", "4. Which effect is missing (forward selection by likelihood ratio)"] + _selection_text(d.selection)
    for e in d.selection.missing:
        lines += [f"   Physics of {e}: {physics(e)}"]
    if d.after is not None:
        title = "5. Added" if d.added else "5. If you add the missing effect(s) (radseek diagnose --add ...)"
        lines += ["", f"{title}: {model_name(d.after.effects)}"]
        b, a = d.current, d.after
        lines.append(f"  deviance/dof {b.gof.deviance_per_dof:.3f} -> {a.gof.deviance_per_dof:.3f} "
                     f"(expected {a.gof.expected_per_dof:.3f} +- {a.gof.sd_per_dof:.3f}), p {b.gof.p_value:.2g} -> "
                     f"{a.gof.p_value:.2g}")
        lines.append(f"  residual RMS {b.residual_rms:.2f} -> {a.residual_rms:.2f}")
        if math.isfinite(a.spectral_dev_per_dof) and math.isfinite(b.spectral_dev_per_dof):
            lines.append(f"  spectral deviance/dof {b.spectral_dev_per_dof:.3f} -> {a.spectral_dev_per_dof:.3f}")
        if b.source_error_m is not None and a.source_error_m is not None:
            lines.append(f"  source error {b.source_error_m:.3f} m -> {a.source_error_m:.3f} m (truth.json)")
        lines += _sources_text(a)
        if d.added:
            for e in d.added:
                lines.append(f"  Physics of {e}: {physics(e)}")
            if d.after_selection is not None:
                lines += ["", "6. Is anything still missing?"] + _selection_text(d.after_selection)
    walls = unmapped_walls(d.final.fit, d.dataset.frames)
    if walls:
        lines += ["", "Unmapped walls (paste into scenario.json's \"walls\"; mu x thickness is what the shadow "
                      "measures):"]
        for w in walls:
            e = w["errors"]
            lines.append(f"  {json.dumps({k: w[k] for k in ('start', 'end', 'thickness', 'height', 'material')})}"
                         f"  mu_per_m {_fmt(w['mu_per_m'], e.get('mu_per_m'))}, centre +- "
                         f"{e.get('centre_x', float('nan')):.2g} / {e.get('centre_y', float('nan')):.2g} m")
            lo, hi = w["distance_range_95_m"]
            lines.append(f"    its centre is {w['distance_from_source_m']:.2f} m from the source at bearing "
                         f"{w['bearing_deg']:.0f} deg; the shadow allows {lo:.2f}-{hi:.2f} m along that bearing (95 %, "
                         "length scaling with distance): the counts fix the sector, not the distance")
    if d.dropped:
        lines += ["", f"Named by the forward selection but not needed once the others are in (dropped): "
                      f"{', '.join(d.dropped)}"]
        short = [r for r in d.backward if r["below_full"] > BELOW_FULL_NOTE]
        if short:
            by = ", ".join(format(r["below_full"], ".1f") for r in short)
            lines += [f"  The fit without {', '.join(r['effect'] for r in short)} reached a lower -log L (by {by}) "
                      "than the fit with every effect: that fit had stopped in a worse minimum, so with several "
                      "minima the answer can depend on the search."]
    if d.nuclide is not None:
        nu = d.nuclide
        lines += ["", f"Second source's nuclide (from the flight's spectra): {nu.nuclide or 'undetermined'}"
                      f"{f' (runner-up {nu.runner_up}, log-likelihood gap {nu.gap:.1f})' if nu.runner_up else ''}",
                  f"  {nu.note}"]
    if d.unexplained:
        hit = d.off_list
        why = hit.text() if hit is not None else misfit_text(d.final_report or d.final, d.dataset.frames)
        lines += ["", f"Verdict: the model still misses something none of the candidates explains ({why})."]
        if d.partial:
            lines.append(f"  Effects that help but do not make the fit adequate (not the missing physics): "
                         f"{', '.join(d.partial)}")
    else:
        verdict = final_missing(d)
        lines += ["", "Verdict: " + (f"missing effect(s): {', '.join(verdict)}" if verdict else
                                     f"{model_name(final.effects)} is adequate at alpha {d.alpha}.")]
    if d.hotspots:
        lines.append("  Where the residual lives (z = (observed - expected) / sqrt(expected), largest first):")
        lines += [f"    {h['kind']:9s} z {h['z']:+7.1f}  {h['where']}" for h in d.hotspots]
    if plots:
        lines += ["", "Plots:"] + [f"  {p}" for p in plots]
    return "\n".join(lines) + "\n"


def final_missing(d: Diagnosis) -> list[str]:
    """Effects whose addition is supported by their test and leaves an adequate fit (``verdict``)."""
    return list(d.missing)


def _model_json(rep: ModelReport) -> dict[str, Any]:
    return {
        "model": list(rep.effects),
        "deviance_per_dof": float(rep.gof.deviance_per_dof),
        "deviance_per_dof_expected": float(rep.gof.expected_per_dof),
        "deviance_per_dof_sd": float(rep.gof.sd_per_dof),
        "p_value": float(rep.gof.p_value),
        "residual_rms": float(rep.residual_rms),
        "spectral_deviance_per_dof": None if not math.isfinite(rep.spectral_dev_per_dof) else rep.spectral_dev_per_dof,
        "sources": rep.sources,
        "background_cps": float(rep.fit.values.get("background_cps", float("nan"))),
        "effect_params": {k: {"value": v, "error": e} for k, (v, e) in rep.effect_params.items()},
        "source_error_m": rep.source_error_m,
    }


def json_report(d: Diagnosis, plots: list[str] | None = None) -> dict[str, Any]:
    added = bool(d.added) and d.after is not None
    final = d.after if added else d.current
    sel = d.after_selection if added and d.after_selection is not None else d.selection
    out: dict[str, Any] = {"dataset": d.dataset.name, "alpha": d.alpha}
    out.update(_model_json(final))
    out["candidates"] = [c.to_json() for c in sel.first]
    out["selection_steps"] = [{"model": list(st.effects), "chosen": st.chosen,
                               "candidates": [c.to_json() for c in st.candidates]} for st in sel.steps]
    out["missing"] = final_missing(d)
    out["partial"] = list(d.partial)
    out["unexplained"] = bool(d.unexplained)
    out["residual_hotspots"] = list(d.hotspots)
    out["source_motion"] = d.motion.to_json() if d.motion is not None else None
    out["background_time"] = d.background_time.to_json() if d.background_time is not None else None
    out["unmapped_walls"] = unmapped_walls(d.final.fit, d.dataset.frames)
    out["dropped"] = list(d.dropped)
    out["backward_check"] = [dict(r) for r in d.backward]
    out["physics"] = {e: physics(e) for e in (*d.missing, *d.partial)}
    out["trends"] = [{"feature": t.feature, "chi2": t.chi2, "dof": t.dof, "p_value": t.p_value,
                      "summary": describe_trend(t, unit_of(t.feature), d.alpha)} for t in final.trends.values()]
    if d.spectral is not None:
        sp = d.spectral
        out["spectral"] = {"gain_drift_percent_per_min": sp.percent_per_min, "error": sp.error, "lr": sp.lr,
                           "p_value": sp.p_value}
    if added:
        out["before"] = _model_json(d.current)
        out["added"] = list(d.added)
    elif d.after is not None:
        out["with_missing"] = _model_json(d.after)
    if d.nuclide is not None:
        nu = d.nuclide
        entry = {"value": nu.nuclide or "undetermined", "runner_up": nu.runner_up, "log_likelihood_gap": nu.gap,
                 "log_likelihood": dict(nu.log_likelihood), "note": nu.note}
        for block in (out, out.get("with_missing")):
            if block is not None:
                block["effect_params"]["second_source.nuclide"] = entry
        for c in out["candidates"]:
            if c["effect"] == "second_source":
                c["params"]["second_source.nuclide"] = entry["value"]
    out["plots"] = list(plots or [])
    return out
