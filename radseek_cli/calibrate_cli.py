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
(``radseek.photon_lines.source_lines``), ``U-nat`` (natural uranium without its long-lived daughters), or
``HEAD@AGE`` (``Th-232@5y``, ``U-nat@60y``, ``Ra-226@70y``; AGE in y or d, at most 1000 y): the head's element
separated AGE ago, its progeny grown in since (pydecay's Bateman solution). ``--predict FILE=NUCLIDE`` evaluates
the fitted response on a spectrum it was not fitted to (only the amplitude fitted, pile-up rescaled by rate).
``--json`` gives ``spectra`` and ``predicted``, one entry per file, each with its ``total_variation_32``.

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

from radseek_cli.flight_cli import _positive
from radseek_io.detector_file import DetectorFileError
from radseek_io.outdir import OutputDirError
from radseek_io.spectrum_io import SpectrumFileError
from spectra.calibration import _versus, refuse_non_finite, run, run_joint

__all__ = ["main", "parse_pair", "refuse_non_finite", "run", "run_joint"]


def parse_pair(text: str) -> tuple[str, list[str]]:
    """``FILE=NUCLIDE[,NUCLIDE...]`` -> (file, nuclides); the last ``=`` splits, so a file name may hold one."""
    path, sep, nucs = text.rpartition("=")
    names = [n.strip() for n in nucs.split(",") if n.strip()]
    if not sep or not path or not names:
        raise ValueError(f"{text!r}: expected FILE=NUCLIDE (e.g. Eu152.xml=Eu-152, or thorium.csv=Th-232)")
    return path, names


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
    ap.add_argument("--live-time", type=_positive, metavar="S",
                    help="live time (s) of a CSV spectrum that states none (a file's own figure is kept)")
    ap.add_argument("--max-mb", type=_positive, help="raise the file size limit (default 64 MB)")
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
        reading = {"live_time_s": a.live_time, "max_bytes": int(a.max_mb * 1e6) if a.max_mb else None}
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
                          log=log, force=a.force, **reading)
        else:
            r = run(a.spectrum[0], a.nuclide, a.background, a.detector, a.no_fit, a.out, a.plot, effects,
                    log=log, force=a.force, **reading)
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
