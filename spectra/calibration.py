"""Calibration runs: the physical response fitted to measured spectra of one unit (``spectra.fit``), what it
misses, and what it predicts on spectra it was not fitted to; the detector file written. ``radseek calibrate``
(``radseek_cli.calibrate_cli``) is its command line; ``benchmarks/real_spectra.py`` runs it on the shared real
spectra.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from radseek.photon_lines import is_chain_source
from radseek_io.detector_file import DetectorFile, first_non_finite, read_detector_file
from radseek_io.outdir import check_output_file
from radseek_io.spectrum_io import read_spectrum

TEMPLATE_NUCLIDES = ("Cs-137", "Co-60", "Ba-133", "Am-241")
TEMPLATE_GRID = np.arange(0.0, 3000.0 + 1e-9, 4.0)
NOT_IDENTIFIABLE = [{"effect": "dead_time", "why": "changes the total rate, not the shape of one spectrum: measure "
                     "the rate at two distances (or use the flight's close pass) to fit tau"}]


def templates(params: dict[str, float], nuclides: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Measured-energy cumulative spectrum per nuclide (deposited energy, resolution applied), normalised to 1."""
    from detector_fw_sim import response
    from spectra import model as M

    crystal = M.crystal_of(params)
    out = {}
    for nuc in nuclides:
        lines = response.nuclide_response(nuc, crystal, round(params["fwhm_at_662"], 6),
                                          round(params["backscatter_fraction"], 6))
        cdf = sum(r.photons_per_decay * r.cdf for r in lines)
        c = np.interp(TEMPLATE_GRID, response.energy_grid(), cdf)
        out[nuc] = c / max(c[-1], 1e-300)
    return out


def template_nuclides(nuclides) -> tuple[str, ...]:
    """Nuclides the detector file carries a template for: the calibrated ones and ``TEMPLATE_NUCLIDES``; a natural
    chain (a chain head, natural uranium, ``HEAD@AGE``) is a calibration source, not a flight source, so it gets
    none."""
    return tuple(dict.fromkeys([n for n in nuclides if not is_chain_source(n)] + list(TEMPLATE_NUCLIDES)))


def run(spectrum: str, nuclides: list[str], background: str | None = None, detector: str | None = None,
        no_fit: bool = False, out: str | None = None, plot: str | None = None, effects: list[str] | None = None,
        log=None, force: bool = False, live_time_s: float | None = None, max_bytes: int | None = None) -> dict:
    """The single form; ``live_time_s`` is the live time of a CSV that states none, ``max_bytes`` the file size
    limit (``read_spectrum``)."""
    from spectra import fit as F
    from spectra import model as M

    if out and not no_fit:
        check_output_file(out, force=force)
    _check_nuclides(nuclides)
    sp = read_spectrum(spectrum, live_time_s=live_time_s, max_bytes=max_bytes)
    bg = read_spectrum(background, live_time_s=live_time_s, max_bytes=max_bytes) if background else None
    energy_law = None
    background_scale = None
    problem = F.Problem(sp, tuple(nuclides), bg)
    start = M.baseline_params()
    det = None
    if detector:
        det = read_detector_file(detector)
        start.update({k: v for k, v in det.parameters.items() if k in M.PARAMS})
    base = F.evaluate(problem, M.baseline_params())
    base_d = F.shape_distances(problem, base.shape)
    rate = float(sp.counts.sum()) / sp.livetime
    if det is not None and "pileup_resolving_time_s" in det.parameters:
        # random summing scales with the rate: pileup = 2 r tau, tau the device's resolving time
        start["pileup"] = min(2 * rate * det.parameters["pileup_resolving_time_s"], M.PARAMS["pileup"].hi)
    if no_fit:
        if det is None:
            raise SystemExit("radseek calibrate: --no-fit needs --detector DET.json")
        res = F.evaluate(problem, start)
        res.effects = tuple(det.effects)
        missing = F.residual_regions(problem, res)
        if bg is not None:  # is the background this spectrum's own? (its scale fitted, the response held)
            background_scale = F.fit_background_scale(problem, start)
    else:
        res = F.forward_select(problem, start, tuple(effects) if effects else None, log=log)
        missing = [{"effect": s["added"], "source": M.EFFECT_SOURCES[s["added"]],
                    "deviance_drop": round(s["deviance_drop"], 1),
                    "total_variation_32_after": round(s["total_variation_32"], 4)} for s in res.steps[1:]]
        if bg is not None:
            res, energy_law = _energy_law_from_background(problem, res, bg, log)
    d = F.shape_distances(problem, res.shape)
    params_for_lines = dict(res.params)
    result = {
        "spectrum": str(spectrum), "nuclides": list(nuclides), "background": background,
        "live_time_s": sp.livetime, "no_fit": no_fit,
        "parameters": {k: round(v, 6) for k, v in res.params.items()},
        "errors": {k: float(f"{v:.3g}") for k, v in res.errors.items()},
        "effects": list(res.effects),
        "missing": missing,
        "still_missing": F.residual_regions(problem, res) + NOT_IDENTIFIABLE,
        "lines": F.line_checks(problem, params_for_lines),
        "steps": [{k: (round(v, 4) if isinstance(v, float) else v) for k, v in s.items()} for s in res.steps],
        "deviance": round(res.deviance, 2), "dof": res.dof,
        "deviance_per_dof": round(res.deviance_per_dof, 4),
        "total_variation_32": round(d["total_variation_32"], 4),
        "total_variation_native": round(d["total_variation_native"], 4),
        "baseline": {"deviance_per_dof": round(base.deviance_per_dof, 4),
                     "total_variation_32": round(base_d["total_variation_32"], 4),
                     "total_variation_native": round(base_d["total_variation_native"], 4)},
        "pileup_resolving_time_us": round(res.params["pileup"] / max(2 * rate, 1e-9) * 1e6, 3),
        "energy_law": energy_law,
    }
    if background_scale is not None:
        result["background_scale_free"] = background_scale
    if out and not no_fit:
        tnucs = template_nuclides(nuclides)
        saved = dict(res.params, pileup_resolving_time_s=res.params["pileup"] / max(2 * rate, 1e-9))
        df = DetectorFile(name=sp.serial or Path(spectrum).stem, parameters=saved, errors=dict(res.errors),
                          effects=list(res.effects), missing=result["still_missing"],
                          calibrated_on={"spectrum": Path(spectrum).name, "nuclides": list(nuclides),
                                         "background": Path(background).name if background else None,
                                         "live_time_s": sp.livetime},
                          fit={k: result[k] for k in ("deviance_per_dof", "total_variation_32",
                                                      "total_variation_native", "baseline")},
                          grid_keV=TEMPLATE_GRID, cdf=templates(res.params, tnucs))
        df.write(out)
        result["out"] = str(out)
    if plot:
        from spectra.plots import plot_fit

        plot_fit(problem, res, base, plot, title=f"{Path(spectrum).name} ({', '.join(nuclides)})"
                 + (" - saved response, no refit" if no_fit else ""))
        result["plot"] = str(plot)
    return result


def _check_nuclides(names: list[str]) -> None:
    from radseek.photon_lines import source_lines

    for n in names:
        source_lines(n)  # ValueError naming an unknown nuclide


def _spectrum_summary(F, problem, res, base) -> dict:
    d = F.shape_distances(problem, res.shape)
    b = F.shape_distances(problem, base.shape)
    return {"spectrum": problem.name, "nuclides": list(problem.nuclides),
            "live_time_s": problem.spectrum.livetime, "rate_cps": round(problem.rate_cps, 3),
            "amplitude": float(f"{res.amplitude:.6g}"),
            "deviance": round(res.deviance, 2), "dof": res.dof, "deviance_per_dof": round(res.deviance_per_dof, 4),
            "total_variation_32": round(d["total_variation_32"], 4),
            "total_variation_native": round(d["total_variation_native"], 4),
            "baseline": {"deviance_per_dof": round(base.deviance_per_dof, 4),
                         "total_variation_32": round(b["total_variation_32"], 4),
                         "total_variation_native": round(b["total_variation_native"], 4)},
            "still_missing": F.residual_regions(problem, res),
            "lines": F.line_checks(problem, res.params)}


def run_joint(pairs: list[tuple[str, list[str]]], background: str | None = None, detector: str | None = None,
              no_fit: bool = False, out: str | None = None, plot: str | None = None,
              effects: list[str] | None = None, predict: list[tuple[str, list[str]]] | None = None,
              drift: bool | tuple[int, ...] = False, log=None, force: bool = False, live_time_s: float | None = None,
              max_bytes: int | None = None) -> dict:
    """The joint form: one response fitted to several spectra of one unit (module docstring). ``drift``: True for
    every spectrum after the first, or the indices in ``pairs`` of the spectra that drift; ``live_time_s`` and
    ``max_bytes`` as in :func:`run`, for every file read."""
    from spectra import fit as F
    from spectra import model as M

    if out and not no_fit:
        check_output_file(out, force=force)
    for _, nucs in list(pairs) + list(predict or []):
        _check_nuclides(nucs)
    bg = read_spectrum(background, live_time_s=live_time_s, max_bytes=max_bytes) if background else None

    def problem(path: str, nucs: list[str]):
        return F.Problem(read_spectrum(path, live_time_s=live_time_s, max_bytes=max_bytes), tuple(nucs), bg,
                         name=str(path))

    joint = F.Joint(tuple(problem(f, n) for f, n in pairs), drift=drift)
    start = M.baseline_params()
    det = read_detector_file(detector) if detector else None
    if det is not None:
        start.update({k: v for k, v in det.parameters.items() if k in M.PARAMS})
        if "pileup_resolving_time_s" in det.parameters:  # pileup = 2 r tau, r the first spectrum's rate
            start["pileup"] = min(2 * joint.parts[0].rate_cps * det.parameters["pileup_resolving_time_s"],
                                  M.PARAMS["pileup"].hi)
    elif no_fit:
        raise SystemExit("radseek calibrate: --no-fit needs --detector DET.json")
    base = F.evaluate(joint, M.baseline_params())
    if no_fit:
        res = F.evaluate(joint, start)
        res.effects = tuple(det.effects)
        missing = []
    else:
        res = F.forward_select(joint, start, tuple(effects) if effects else None, log=log)
        missing = [{"effect": st["added"], "source": M.EFFECT_SOURCES[st["added"]],
                    "deviance_drop": round(st["deviance_drop"], 1),
                    "total_variation_32_after": [round(v, 4) for v in st["per_spectrum"]]} for st in res.steps[1:]]
    spectra = []
    for k, (pr, r, b) in enumerate(zip(joint.parts, res.parts, base.parts, strict=True)):
        row = _spectrum_summary(F, pr, r, b)
        if k in joint.drifting():
            row["drift"] = {"gain": round(res.params[f"gain_drift_{k}"], 6),
                            "offset_keV": round(res.params[f"offset_drift_keV_{k}"], 3)}
        spectra.append(row)
    rate0 = joint.parts[0].rate_cps
    tau = res.params["pileup"] / max(2 * rate0, 1e-9)
    shared = {k: v for k, v in res.params.items() if k in M.PARAMS}
    predicted = []
    for f, nucs in predict or []:
        pr = problem(f, nucs)
        q = dict(shared, pileup=min(2 * pr.rate_cps * tau, M.PARAMS["pileup"].hi))
        predicted.append(_spectrum_summary(F, pr, F.evaluate(pr, q), F.evaluate(pr, M.baseline_params())))
    result = {
        "form": "joint", "spectra": spectra, "predicted": predicted, "background": background,
        "no_fit": no_fit, "drift": _drift_json(drift),
        "parameters": {k: round(v, 6) for k, v in res.params.items()},
        "errors": {k: float(f"{v:.3g}") for k, v in res.errors.items()},
        "effects": list(res.effects), "missing": missing,
        "steps": [{k: (round(v, 4) if isinstance(v, float) else v) for k, v in st.items()} for st in res.steps],
        "deviance": round(res.deviance, 2), "dof": res.dof, "deviance_per_dof": round(res.deviance_per_dof, 4),
        "total_variation_32": max(sp["total_variation_32"] for sp in spectra),
        "total_variation_native": max(sp["total_variation_native"] for sp in spectra),
        "pileup_resolving_time_us": round(tau * 1e6, 3),
    }
    if out and not no_fit:
        saved = dict(shared, pileup_resolving_time_s=tau)
        errors = {k: v for k, v in res.errors.items() if k in M.PARAMS}
        df = DetectorFile(name=joint.parts[0].spectrum.serial or Path(pairs[0][0]).stem, parameters=saved,
                          errors=errors, effects=list(res.effects),
                          missing=[w for sp in spectra for w in sp["still_missing"]] + NOT_IDENTIFIABLE,
                          calibrated_on={"spectra": [{"spectrum": Path(f).name, "nuclides": list(n),
                                                      "live_time_s": pr.spectrum.livetime}
                                                     for (f, n), pr in zip(pairs, joint.parts, strict=True)],
                                         "background": Path(background).name if background else None,
                                         "drift": _drift_json(drift)},
                          fit={"deviance_per_dof": result["deviance_per_dof"],
                               "total_variation_32": result["total_variation_32"],
                               "total_variation_native": result["total_variation_native"],
                               "per_spectrum": {Path(sp["spectrum"]).name: sp["total_variation_32"] for sp in spectra},
                               "predicted": {Path(sp["spectrum"]).name: sp["total_variation_32"] for sp in predicted}},
                          grid_keV=TEMPLATE_GRID,
                          cdf=templates(shared, template_nuclides([n for _, ns in pairs for n in ns])))
        df.write(out)
        result["out"] = str(out)
    if plot:
        from spectra.plots import plot_fit

        stem = Path(plot)
        written = []
        for pr, r, b, (f, nucs) in zip(joint.parts, res.parts, base.parts, pairs, strict=True):
            path = stem.with_name(f"{stem.stem}-{Path(f).stem}{stem.suffix or '.png'}")
            plot_fit(pr, r, b, path, title=f"{Path(f).name} ({', '.join(nucs)}), joint fit")
            written.append(str(path))
        result["plot"] = written
    return result


def _drift_json(drift: bool | tuple[int, ...]) -> bool | list[int]:
    return drift if isinstance(drift, bool) else sorted(int(k) for k in drift)


def _energy_law_from_background(problem, res, bg, log=None):
    """The energy law's offset from the background's natural lines (``spectra.energy_law``); applied (the gain
    refitted with the offset held) only when the background pins it within ``MAX_OFFSET_ERROR_KEV``."""
    from detector_fw_sim import response
    from spectra import energy_law as EL
    from spectra import fit as F

    el = EL.fit_background_offset(bg, res.params, response.main_line_keV(problem.nuclides[0]))
    out = el.as_dict()
    if el.identified:
        steps = res.steps
        res = F.fit(problem, dict(res.params, offset_keV=el.offset_keV, gain=el.gain), res.effects)
        res.steps = steps
        out["applied"] = True
    else:
        out["applied"] = False
        out["why"] = (f"the background's natural lines pin the offset to +-{el.offset_error_keV:.2g} keV only "
                      f"(needed: <= {EL.MAX_OFFSET_ERROR_KEV} keV); the law stays gain-only")
    if log:
        log(f"energy law from the background lines: offset {el.offset_keV:+.2f} +- {el.offset_error_keV:.2g} keV"
            f" ({'applied' if out['applied'] else 'not identified'})")
    return res, out


def refuse_non_finite(result: dict) -> None:
    """No NaN or infinity in ``--json`` (strict JSON): a ValueError naming the field instead."""
    bad = first_non_finite(result)
    if bad is not None:
        raise ValueError(f"result field '{bad[0]}' is {bad[1]!r}: refusing to print non-finite numbers "
                         "(check the spectrum's counts and live time)")


def _versus(w: dict) -> str:
    """A still-missing window, measured against the model, for people."""
    if w.get("relative") is None:
        return (f"measured {w['measured_minus_model'] + w.get('model_counts', 0.0):.0f} counts where the model "
                f"expects {w.get('model_counts', 0.0):.2g} (an emission or a background the model lacks)")
    return f"measured {100 * w['relative']:+.1f} % vs model"
