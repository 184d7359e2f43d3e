"""Benchmark: the response calibrated on a real RadiaCode-102 Cs-137 spectrum, checked on Ba-133 and Am-241.

    python -m benchmarks.real_spectra [--out docs/img] [--json results.json]

Fits ``Cs137_b.xml`` minus ``bg.xml`` (forward selection over response effects), saves the detector file, then
evaluates it without refit on ``Ba133_a.xml``, ``Co60_a.xml`` and ``Eu152_b.xml`` (same device, day and background)
and ``data_am241.n42`` (another
RadiaCode-102, no background of its own: evaluated with and without ``bg.xml`` as a stand-in). Prints the shape
distances before (the emulator's response) and after calibration, and each strong photopeak's shift and FWHM
ratio against the Cs-137 response (``spectra.fit.line_checks``), what ``bg.xml``'s natural lines say about the
energy law (``spectra.energy_law``), the background scale refitted with the response held
(``spectra.fit.fit_background_scale``), and the share of Am-241's net counts above 170 keV, where it emits no line.
Targets (issue 15): Cs-137 total_variation_32 <= 0.03; other nuclides <= 0.04 with no refit.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from spectra.calibrate_cli import run

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "real-spectra"


def _share_above(name: str, nuclide: str, background: str | None, above_keV: float) -> float:
    import numpy as np

    from radseek.spectrum_files import read_spectrum
    from spectra import fit as F

    prob = F.Problem(read_spectrum(DATA / name), (nuclide,), read_spectrum(DATA / background) if background else None)
    e32 = F.reference_edges()
    net = np.maximum(F._rebin_signed(prob.net(), prob.boundaries, e32), 0.0)
    keep = e32[:-1] >= F.TV_MIN_KEV
    return float(net[keep & (e32[:-1] >= above_keV)].sum() / net[keep].sum())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.real_spectra")
    ap.add_argument("--out", default="docs/img", help="folder for the plots and the detector file")
    ap.add_argument("--json", help="write all results as JSON")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    det = out / "rc102-001272.detector.json"
    t0 = time.process_time()
    cs = run(str(DATA / "Cs137_b.xml"), ["Cs-137"], str(DATA / "bg.xml"), out=str(det),
             plot=str(out / "real-cs137-calibrated.png"), log=lambda s: print("  " + s, flush=True))
    rows = {"Cs-137 (fitted)": cs}
    rows["Ba-133 (no refit)"] = run(str(DATA / "Ba133_a.xml"), ["Ba-133"], str(DATA / "bg.xml"), str(det), True,
                                    plot=str(out / "real-ba133-no-refit.png"))
    # the same device, day and background as Cs-137 (radiacode-tools' dead-time test data): the check the issue
    # keeps back for nuclides we did not fit
    rows["Co-60 (no refit)"] = run(str(DATA / "Co60_a.xml"), ["Co-60"], str(DATA / "bg.xml"), str(det), True,
                                   plot=str(out / "real-co60-no-refit.png"))
    rows["Eu-152 (no refit)"] = run(str(DATA / "Eu152_b.xml"), ["Eu-152"], str(DATA / "bg.xml"), str(det), True,
                                    plot=str(out / "real-eu152-no-refit.png"))
    rows["Am-241 (no refit, bg.xml as stand-in)"] = run(str(DATA / "data_am241.n42"), ["Am-241"], str(DATA / "bg.xml"),
                                                       str(det), True, plot=str(out / "real-am241-no-refit.png"))
    rows["Am-241 (no refit, no background)"] = run(str(DATA / "data_am241.n42"), ["Am-241"], None, str(det), True)
    print(f"{'spectrum':<40} {'TV32 before':>11} {'TV32 after':>10} {'native before':>13} {'native after':>12} "
          f"{'dev/dof':>8}")
    for name, r in rows.items():
        b = r["baseline"]
        print(f"{name:<40} {b['total_variation_32']:>11.4f} {r['total_variation_32']:>10.4f} "
              f"{b['total_variation_native']:>13.4f} {r['total_variation_native']:>12.4f} "
              f"{r['deviance_per_dof']:>8.2f}")
    print("photopeaks against the Cs-137 response (shift of the file energy, FWHM ratio):")
    for name, r in rows.items():
        for ln in r["lines"]:
            print(f"  {name:<40} {ln['line_keV']:>7.1f} keV: {ln['shift_keV']:+6.2f} +- "
                  f"{ln['shift_error_keV']:<5.2g} keV  FWHM x {ln['fwhm_ratio']:.3f} +- {ln['fwhm_ratio_error']:.2g}")
    el = cs.get("energy_law") or {}
    if el:
        print(f"energy law from bg.xml's natural lines: offset {el['offset_keV']:+.2f} +- {el['offset_error_keV']} "
              f"keV ({'applied' if el['applied'] else 'not identified'}); series (decays +- error): "
              + "; ".join(f"{k} {v['decays']:.3g} +- {v['error']:.2g}" for k, v in el["series"].items()))
    print("background scale refitted with the response held (1 = the spectrum's own background):")
    for name, r in rows.items():
        bs = r.get("background_scale_free")
        if bs and bs.get("scale") is not None:
            print(f"  {name:<40} scale {bs['scale']:.3f} +- {bs['scale_error']:<5.2g} "
                  f"TV32 {bs['total_variation_32']:.4f} native {bs['total_variation_native']:.4f}")
    print("share of the net counts above 83 keV that sit above 170 keV (32-channel shares; Am-241 emits no line of "
          ">= 1e-3 per decay there, so for Am-241 this share is a floor on TV32 that no response can lower):")
    for name, (f, nuc, bgf) in {"Am-241, bg.xml": ("data_am241.n42", "Am-241", "bg.xml"),
                                "Am-241, no background": ("data_am241.n42", "Am-241", None)}.items():
        print(f"  {name:<40} {_share_above(f, nuc, bgf, 170.0):.4f}")
    print(f"selected effects: {', '.join(cs['effects'])}; CPU {time.process_time() - t0:.0f} s")
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
