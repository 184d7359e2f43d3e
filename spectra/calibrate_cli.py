"""``radseek calibrate``: fit the physical response to a measured spectrum and say what the emulator's response misses.

    radseek calibrate Cs137_b.xml --nuclide Cs-137 --background bg.xml --out rc102.json --plot cs137.png
    radseek calibrate Ba133_a.xml --nuclide Ba-133 --background bg.xml --detector rc102.json --no-fit --json

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

from radseek.detector_file import DetectorFile, DetectorFileError, read_detector_file
from radseek.spectrum_files import SpectrumFileError, read_spectrum

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


def run(spectrum: str, nuclides: list[str], background: str | None = None, detector: str | None = None,
        no_fit: bool = False, out: str | None = None, plot: str | None = None, effects: list[str] | None = None,
        log=None) -> dict:
    from spectra import fit as F
    from spectra import model as M

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
    rate = float(sp.counts.sum()) / sp.live_time_s
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
        "live_time_s": sp.live_time_s, "no_fit": no_fit,
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
        tnucs = tuple(dict.fromkeys(list(nuclides) + list(TEMPLATE_NUCLIDES)))
        saved = dict(res.params, pileup_resolving_time_s=res.params["pileup"] / max(2 * rate, 1e-9))
        df = DetectorFile(name=sp.serial or Path(spectrum).stem, parameters=saved, errors=dict(res.errors),
                          effects=list(res.effects), missing=result["still_missing"],
                          calibrated_on={"spectrum": Path(spectrum).name, "nuclides": list(nuclides),
                                         "background": Path(background).name if background else None,
                                         "live_time_s": sp.live_time_s},
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
                  f"channels, measured {100 * w['relative']:+.1f} % vs model")
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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="radseek calibrate", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("spectrum", help="measured spectrum (N42, RadiaCode XML, .spe, .chn, CSV)")
    ap.add_argument("--nuclide", action="append", required=True, help="nuclide in the spectrum (repeatable)")
    ap.add_argument("--background", help="measured background spectrum (scaled by live time and added)")
    ap.add_argument("--detector", help="detector file to start from (or, with --no-fit, to evaluate)")
    ap.add_argument("--no-fit", action="store_true", help="evaluate --detector on this spectrum, no refit")
    ap.add_argument("--out", help="write the calibrated detector file (JSON)")
    ap.add_argument("--plot", help="write measured vs model with residuals (PNG)")
    ap.add_argument("--effects", help="comma-separated candidate effects (default: all)")
    ap.add_argument("--json", action="store_true", help="print the result as JSON")
    a = ap.parse_args(argv)
    try:
        from spectra import model as M

        effects = [e.strip() for e in a.effects.split(",")] if a.effects else None
        for e in effects or []:
            if e not in M.EFFECTS:
                ap.error(f"unknown effect {e!r}; known: {', '.join(M.EFFECTS)}")
        r = run(a.spectrum, a.nuclide, a.background, a.detector, a.no_fit, a.out, a.plot, effects,
                log=None if a.json else (lambda s: print("  " + s, file=sys.stderr)))
    except (SpectrumFileError, DetectorFileError, ValueError) as exc:
        print(f"radseek calibrate: {exc}", file=sys.stderr)
        return 2
    if a.json:
        print(json.dumps(r, indent=1))
    else:
        _print_human(r)
    return 0


if __name__ == "__main__":
    sys.exit(main())
