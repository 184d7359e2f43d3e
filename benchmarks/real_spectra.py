"""Benchmark: the response calibrated on a real RadiaCode-102 Cs-137 spectrum, checked on Ba-133 and Am-241.

    python -m benchmarks.real_spectra [--out docs/img] [--json results.json]

Fits ``Cs137_b.xml`` minus ``bg.xml`` (forward selection over response effects), saves the detector file, then
evaluates it without refit on ``Ba133_a.xml`` (same device, same background) and ``data_am241.n42`` (another
RadiaCode-102, no background of its own: evaluated with and without ``bg.xml`` as a stand-in). Prints the shape
distances before (the emulator's response) and after calibration, and each strong photopeak's shift and FWHM
ratio against the Cs-137 response (``spectra.fit.line_checks``). Targets (issue 15): Cs-137 total_variation_32
<= 0.03; Ba-133 and Am-241 <= 0.04 with no refit.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from spectra.calibrate_cli import run

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "real-spectra"


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
    print(f"selected effects: {', '.join(cs['effects'])}; CPU {time.process_time() - t0:.0f} s")
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
