"""``radseek calibrate``: fit the physical response to measured spectra and say what the emulator's response misses.

    radseek calibrate Cs137_b.xml --nuclide Cs-137 --background bg.xml --out rc102.json --plot cs137.png
    radseek calibrate Ba133_a.xml --nuclide Ba-133 --background bg.xml --detector rc102.json --no-fit --json
    radseek calibrate Cs137_b.xml=Cs-137 Eu152_b.xml=Eu-152 --background bg.xml --out rc102.json \
        --predict Co60_a.xml=Co-60 --predict Ba133_a.xml=Ba-133 --json

Joint form (``FILE=NUCLIDE[,NUCLIDE...]``, several spectra of one unit): one response fitted to all of them
(``spectra.fit.Joint``), each spectrum its own amplitude; the pile-up share follows each spectrum's rate (one
resolving time); ``--drift`` gives every spectrum after the first its own gain and offset (sessions days apart),
``--drift-of FILE`` that spectrum only (one session days after the others). A nuclide may be a natural chain head in
secular equilibrium (Th-232, U-238, U-235, Ra-226; K-40), its lines walked down the chain from pydecay
(``radseek.photon_lines.source_lines``). ``--predict FILE=NUCLIDE`` evaluates the fitted response on a spectrum it
was not fitted to (only the amplitude fitted, pile-up rescaled by rate). ``--json`` gives ``spectra`` and
``predicted``, one entry per file, each with its ``total_variation_32``.

``--out`` never replaces an existing file unless ``--force``; a NaN or infinity is never written (to the detector
file or ``--json``): the command refuses and names the field.

Without ``--no-fit``: forward selection over response effects (``spectra.fit``) from the emulator's response (or
from ``--detector``'s parameters), printing each effect it adds and the deviance and 32-channel shape distance
after it. With ``--no-fit``: the saved response on this spectrum, only the amplitude fitted. ``--json`` prints
parameters, errors, missing, deviance_per_dof, total_variation_32, total_variation_native and the baseline's
distances, and ``lines``: each strong photopeak's shift (keV) and FWHM ratio against the response (``fit.line_checks``),
which shows what one Cs-137 photopeak cannot calibrate (the light yield and resolution at low energies). Dead time
changes only the total rate, not the shape of one spectrum: it is reported as not identifiable.

With ``--background`` and a fit, ``energy_law`` says what the background's natural lines (U-238 and Th-232 series,
K-40; ``spectra.energy_law``) tell about the energy law's offset below the calibration line, and whether it was
applied (only when they pin it within 1 keV). With ``--no-fit`` and ``--background``, ``background_scale_free``
refits the background's scale with the response held: near 1 when the background is the spectrum's own, and the
shape distances on that footing when it is a stand-in.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from radseek.photon_lines import NATURAL_CHAINS
from radseek_io.detector_file import DetectorFile, DetectorFileError, first_non_finite, read_detector_file
from radseek_io.outdir import OutputDirError, check_output_file
from radseek_io.spectrum_io import SpectrumFileError, read_spectrum

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
    chain is a calibration source, not a flight source, so it gets none."""
    return tuple(dict.fromkeys([n for n in nuclides if n not in NATURAL_CHAINS] + list(TEMPLATE_NUCLIDES)))


def run(spectrum: str, nuclides: list[str], background: str | None = None, detector: str | None = None,
        no_fit: bool = False, out: str | None = None, plot: str | None = None, effects: list[str] | None = None,
        log=None, force: bool = False) -> dict:
    from spectra import fit as F
    from spectra import model as M

    if out and not no_fit:
        check_output_file(out, force=force)
    sp = read_spectrum(spectrum)
    bg = read_spectrum(background) if background else None
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


def parse_pair(text: str) -> tuple[str, list[str]]:
    """``FILE=NUCLIDE[,NUCLIDE...]`` -> (file, nuclides); the last ``=`` splits, so a file name may hold one."""
    path, sep, nucs = text.rpartition("=")
    names = [n.strip() for n in nucs.split(",") if n.strip()]
    if not sep or not path or not names:
        raise ValueError(f"{text!r}: expected FILE=NUCLIDE (e.g. Eu152.xml=Eu-152, or thorium.csv=Th-232)")
    return path, names


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
              drift: bool | tuple[int, ...] = False, log=None, force: bool = False) -> dict:
    """The joint form: one response fitted to several spectra of one unit (module docstring). ``drift``: True for
    every spectrum after the first, or the indices in ``pairs`` of the spectra that drift."""
    from spectra import fit as F
    from spectra import model as M

    if out and not no_fit:
        check_output_file(out, force=force)
    for _, nucs in list(pairs) + list(predict or []):
        _check_nuclides(nucs)
    bg = read_spectrum(background) if background else None

    def problem(path: str, nucs: list[str]):
        return F.Problem(read_spectrum(path), tuple(nucs), bg, name=str(path))

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


def _print_human(r: dict) -> None:
    print(f"{r['spectrum']}: {', '.join(r['nuclides'])}, live time {r['live_time_s']:g} s")
    b = r["baseline"]
    print(f"  emulator's response: deviance/dof {b['deviance_per_dof']:.2f}, total variation 32-ch "
          f"{b['total_variation_32']:.4f}, native {b['total_variation_native']:.4f}")
    if not r["no_fit"]:
        print("  what the response was missing (forward selection):")
        for m in r["missing"]:
            print(f"    + {m['effect']:<18} deviance -{m['deviance_drop']:<9} "
                  f"TV32 -> {m['total_variation_32_after']:.4f}"
                  f"   ({m['source']})")
    print(f"  {'saved' if r['no_fit'] else 'calibrated'} response: deviance/dof {r['deviance_per_dof']:.2f}, total "
          f"variation 32-ch {r['total_variation_32']:.4f}, native {r['total_variation_native']:.4f}")
    print("  parameters:")
    for k, v in r["parameters"].items():
        err = r["errors"].get(k)
        print(f"    {k:<22} {v:.5g}" + (f" +- {err:.2g}" if err else ""))
    print("  still missing (largest deviance windows):")
    for w in r["still_missing"]:
        if "from_keV" in w:
            print(f"    {w['from_keV']:.0f}-{w['to_keV']:.0f} keV: deviance {w['deviance']:.0f} over {w['channels']} "
                  f"channels, {_versus(w)}")
        else:
            print(f"    {w['effect']}: {w['why']}")
    if r["lines"]:
        print("  photopeaks, measured against the response (local shift of the file energy, FWHM ratio):")
        for ln in r["lines"]:
            print(f"    {ln['line_keV']:>8.1f} keV: shift {ln['shift_keV']:+.2f} +- {ln['shift_error_keV']:.2g} keV "
                  f"({100 * ln['shift_relative']:+.2f} %), "
                  f"FWHM x {ln['fwhm_ratio']:.3f} +- {ln['fwhm_ratio_error']:.2g}")
    bs = r.get("background_scale_free")
    if bs and bs.get("scale") is not None:
        print(f"  background scale refitted (response held): {bs['scale']:.3f} +- {bs['scale_error']:.2g}, "
              f"TV32 {bs['total_variation_32']:.4f}, native {bs['total_variation_native']:.4f}")
    el = r.get("energy_law")
    if el:
        err = f"{el['offset_error_keV']:.2g}" if el["offset_error_keV"] is not None else "inf"
        print(f"  energy law from the background's natural lines: offset {el['offset_keV']:+.2f} +- {err} keV, "
              + ("applied" if el["applied"] else "not applied"))
    for k in ("out", "plot"):
        if k in r:
            print(f"  wrote {r[k]}")


def _print_joint(r: dict) -> None:
    print(f"joint calibration on {len(r['spectra'])} spectra" + (" (per-spectrum drift)" if r["drift"] else "")
          + (f", background {r['background']}" if r["background"] else ""))
    if not r["no_fit"]:
        print("  what the response was missing (forward selection; TV32 per spectrum after it):")
        for m in r["missing"]:
            tv = " / ".join(f"{v:.4f}" for v in m["total_variation_32_after"])
            print(f"    + {m['effect']:<20} deviance -{m['deviance_drop']:<9} TV32 {tv}   ({m['source']})")
    print(f"  deviance/dof {r['deviance_per_dof']:.2f}; pile-up resolving time {r['pileup_resolving_time_us']:.2f} us")
    print("  parameters:")
    for k, v in r["parameters"].items():
        err = r["errors"].get(k)
        print(f"    {k:<22} {v:.5g}" + (f" +- {err:.2g}" if err else ""))
    for title, rows in (("fitted", r["spectra"]), ("predicted (no refit, amplitude only)", r["predicted"])):
        if not rows:
            continue
        print(f"  {title}:")
        print(f"    {'spectrum':<28} {'nuclides':<16} {'TV32':>7} {'native':>7} {'dev/dof':>8} "
              f"{'TV32 emulator':>13}")
        for sp in rows:
            print(f"    {Path(sp['spectrum']).name:<28} {','.join(sp['nuclides']):<16} "
                  f"{sp['total_variation_32']:>7.4f} {sp['total_variation_native']:>7.4f} "
                  f"{sp['deviance_per_dof']:>8.2f} {sp['baseline']['total_variation_32']:>13.4f}")
            for w in sp["still_missing"]:
                print(f"      {w['from_keV']:.0f}-{w['to_keV']:.0f} keV: {_versus(w)} (deviance {w['deviance']:.0f})")
            for ln in sp["lines"]:
                print(f"      {ln['line_keV']:>8.1f} keV: shift {ln['shift_keV']:+.2f} +- "
                      f"{ln['shift_error_keV']:.2g} keV, FWHM x {ln['fwhm_ratio']:.3f} +- {ln['fwhm_ratio_error']:.2g}")
    if "out" in r:
        print(f"  wrote {r['out']}")
    for path in r.get("plot") or []:
        print(f"  wrote {path}")


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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="radseek calibrate", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("spectrum", nargs="+",
                    help="measured spectrum (N42, RadiaCode XML, .spe, .chn, CSV) with --nuclide; or several "
                         "FILE=NUCLIDE[,NUCLIDE] pairs of one unit for a joint fit")
    ap.add_argument("--nuclide", action="append", help="nuclide in the spectrum (repeatable; single form)")
    ap.add_argument("--background", help="measured background spectrum (scaled by live time and added)")
    ap.add_argument("--detector", help="detector file to start from (or, with --no-fit, to evaluate)")
    ap.add_argument("--no-fit", action="store_true", help="evaluate --detector on this spectrum, no refit")
    ap.add_argument("--out", help="write the calibrated detector file (JSON); an existing file needs --force")
    ap.add_argument("--force", action="store_true", help="let --out replace an existing file")
    ap.add_argument("--plot", help="write measured vs model with residuals (PNG; joint form: one per spectrum)")
    ap.add_argument("--effects", help="comma-separated candidate effects (default: all)")
    ap.add_argument("--predict", action="append", default=[], metavar="FILE=NUCLIDE",
                    help="joint form: evaluate the fitted response on this spectrum, no refit (repeatable)")
    ap.add_argument("--drift", action="store_true",
                    help="joint form: every spectrum after the first gets its own gain and offset")
    ap.add_argument("--drift-of", action="append", default=[], metavar="FILE",
                    help="joint form: only this spectrum (not the first) gets its own gain and offset, e.g. a "
                         "session days after the others (repeatable)")
    ap.add_argument("--json", action="store_true", help="print the result as JSON")
    a = ap.parse_args(argv)
    joint = any("=" in x for x in a.spectrum)
    if joint:
        if a.nuclide:
            ap.error("give the nuclides as FILE=NUCLIDE pairs or as one SPECTRUM with --nuclide, not both")
    else:
        if len(a.spectrum) != 1:
            ap.error("several spectra need the joint form FILE=NUCLIDE (e.g. Cs137.xml=Cs-137 Eu152.xml=Eu-152)")
        if not a.nuclide:
            ap.error("--nuclide is required with one SPECTRUM (or use the joint form FILE=NUCLIDE)")
        if a.predict or a.drift or a.drift_of:
            ap.error("--predict, --drift and --drift-of belong to the joint form FILE=NUCLIDE")
    try:
        from spectra import model as M

        effects = [e.strip() for e in a.effects.split(",")] if a.effects else None
        for e in effects or []:
            if e not in M.EFFECTS:
                ap.error(f"unknown effect {e!r}; known: {', '.join(M.EFFECTS)}")
        log = None if a.json else (lambda s: print("  " + s, file=sys.stderr))
        if joint:
            pairs = [parse_pair(x) for x in a.spectrum]
            predict = [parse_pair(x) for x in a.predict]
            drift = a.drift
            if a.drift_of:
                if a.drift:
                    ap.error("--drift (every spectrum after the first) or --drift-of FILE, not both")
                files = [f for f, _ in pairs]
                unknown = [f for f in a.drift_of if f not in files[1:]]
                if unknown:
                    ap.error(f"--drift-of {unknown[0]}: not one of the fitted spectra after the first")
                drift = tuple(files.index(f, 1) for f in a.drift_of)
            r = run_joint(pairs, a.background, a.detector, a.no_fit, a.out, a.plot, effects, predict, drift,
                          log=log, force=a.force)
        else:
            r = run(a.spectrum[0], a.nuclide, a.background, a.detector, a.no_fit, a.out, a.plot, effects,
                    log=log, force=a.force)
        refuse_non_finite(r)
    except (SpectrumFileError, DetectorFileError, OutputDirError, ValueError) as exc:
        print(f"radseek calibrate: {exc}", file=sys.stderr)
        return 2
    if a.json:
        print(json.dumps(r, indent=1, allow_nan=False))
    elif joint:
        _print_joint(r)
    else:
        _print_human(r)
    return 0


if __name__ == "__main__":
    sys.exit(main())
