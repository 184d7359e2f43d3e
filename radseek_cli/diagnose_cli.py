"""``radseek diagnose DATASET``: compare the measurement model with a flight, see where it fails, learn which
physical effect is missing, add it and watch the error fall.

    radseek diagnose DATASET [--model EFFECT ...] [--add EFFECT ...] [--json] [--out DIR] [--alpha 0.01] [--jobs N]

Progress goes to stderr; the report (text, or JSON with --json) to stdout; PNG plots to --out
(default runs/diagnose-<dataset name>-<6 hex of its path>/), with the run's fits (fits.pkl): run again with --add
and nothing already fitted is fitted again. Exit status 0 when the analysis ran (whatever it found), 2 on bad input.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

#: fewer usable frames than this are refused: the baseline already fits the source (position, strength) and the
#: background, each candidate effect adds up to 4 parameters, and on a handful of frames no test has power, so
#: "the baseline is adequate" would be said of any flight (it was, of lattice-clean's first 3 frames)
MIN_FRAMES = 50
#: the fits and selections of a run, in its output folder: a later run on the same data (``--add``) reuses them
SAVED_FITS = "fits.pkl"


def __getattr__(name: str) -> Any:
    """``VOCABULARY``: the effects diagnose can name, from ``estimator.diagnose.backend`` (one list to keep; that
    module imports the fit machinery, ~0.6 s, so it is loaded only when an effect is named or this is asked for)."""
    if name == "VOCABULARY":
        from estimator.diagnose.backend import VOCABULARY

        return VOCABULARY
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _effect(name: str) -> str:
    """argparse type of --model and --add: a name of the diagnose vocabulary."""
    from estimator.diagnose.backend import VOCABULARY

    if name not in VOCABULARY:
        raise argparse.ArgumentTypeError(f"invalid choice: {name!r} (choose from {', '.join(VOCABULARY)})")
    return name


def default_out(dataset: Path) -> Path:
    """runs/diagnose-<name>-<6 hex of the dataset's absolute path>: two flights whose folders share a name (two
    runs' ``dataset/``) never write over each other's plots and fits; the same flight finds its fits again."""
    import hashlib

    tag = hashlib.sha1(str(Path(dataset).resolve()).encode()).hexdigest()[:6]
    return Path("runs") / f"diagnose-{Path(dataset).name}-{tag}"


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="radseek diagnose",
        description="Fit the measurement model to a dataset, compare with the measurements, find the missing "
        "physical effect (forward selection by likelihood ratio) and show what adding it changes.",
    )
    p.add_argument("dataset", help="dataset directory (frames.csv, scenario.json, optional truth.json)")
    p.add_argument("--model", nargs="+", action="extend", default=[], metavar="EFFECT", type=_effect,
                   help="effects already in the model (default: the baseline, sources + constant background)")
    p.add_argument("--add", action="append", default=[], metavar="EFFECT", type=_effect,
                   help="refit with this effect added and show before/after (repeatable)")
    p.add_argument("--json", action="store_true", help="print a machine-readable JSON report")
    p.add_argument("--out", type=Path, default=None,
                   help="folder for the PNG plots (default runs/diagnose-<name>-<path hash>/)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--alpha", type=float, default=0.01, help="significance level for naming an effect (0.01)")
    p.add_argument("--starts", type=int, default=8, help="multi-start count of the model fit (8)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--jobs", type=int, default=min(2, len(os.sched_getaffinity(0))),
                   help="processes for the candidate fits of each step (default: 2, or 1 on one core); the "
                   "spectral fit runs alongside them")
    p.add_argument("--quiet", action="store_true", help="no progress messages on stderr")
    return p


def _clean(o: Any) -> Any:
    """JSON-safe: NaN/inf -> None, numpy scalars -> float."""
    if isinstance(o, dict):
        return {str(k): _clean(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_clean(v) for v in o]
    if hasattr(o, "item") and not isinstance(o, str):
        o = o.item()
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if not 0 < args.alpha < 1:
        print("radseek diagnose: --alpha must be in (0, 1)", file=sys.stderr)
        return 2
    if args.jobs < 1:
        print(f"radseek diagnose: --jobs must be >= 1, got {args.jobs}", file=sys.stderr)
        return 2
    if args.starts < 1:
        print(f"radseek diagnose: --starts must be >= 1, got {args.starts}", file=sys.stderr)
        return 2
    from radseek_cli.localize_cli import read_for_cli

    ds = read_for_cli("radseek diagnose", args.dataset, args.quiet, min_frames=MIN_FRAMES,
                      needed_for="to fit the model and test effects")
    if ds is None:
        return 2
    if not np.any(ds.frames.total_counts > 0):
        print(f"radseek diagnose: {ds.path}/frames.csv: all {len(ds.frames)} frames have zero counts in every "
              "channel (columns c00..c31): nothing to compare the model with (was the detector connected?)",
              file=sys.stderr)
        return 2
    wanted = set(args.model) | set(args.add)
    if "wall_attenuation" in wanted and not ds.scenario.walls:
        print(f"radseek diagnose: effect wall_attenuation needs walls, but {ds.path}/scenario.json lists none "
              "(key 'walls')", file=sys.stderr)
        return 2
    from estimator.diagnose.backend import progress
    from estimator.diagnose.runner import diagnose
    from reporting.diagnose_report import json_report, text_report
    from reporting.truth_errors import score_diagnosis

    added = tuple(e for e in dict.fromkeys(args.add) if e not in args.model)
    out = args.out or default_out(ds.path)
    saved = None
    if not args.no_plots or args.out is not None:
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            print(f"radseek diagnose: output folder {out} cannot be created: {exc.strerror or exc}", file=sys.stderr)
            return 2
        saved = out / SAVED_FITS
    try:
        d = diagnose(ds, model=tuple(args.model), add=added, alpha=args.alpha, n_starts=args.starts,
                     seed=args.seed, quiet=args.quiet, jobs=args.jobs, saved=saved)
        score_diagnosis(d, ds.truth)  # the source error vs truth.json, computed here, after the fits
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        print(f"radseek diagnose: the analysis failed on {ds.name}: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    plots: list[str] = []
    if not args.no_plots:
        from estimator.diagnose import plots as P

        progress(f"writing plots to {out}", args.quiet)
        cur = d.current
        plots.append(str(P.plot_features(cur, out / "residuals_vs_features.png")))
        plots.append(str(P.plot_map(cur, out / "residual_map.png", ds.scenario)))
        if d.spectral is not None:
            plots.append(str(P.plot_spectral(d.spectral, out / "spectral_residuals.png", null=True)))
        if d.after is not None:
            tag = "after" if d.added else "with_missing"
            a = d.after
            plots.append(str(P.plot_features(a, out / f"residuals_vs_features_{tag}.png")))
            plots.append(str(P.plot_map(a, out / f"residual_map_{tag}.png", ds.scenario)))
            plots.append(str(P.plot_before_after(cur, a, out / ("before_after.png" if d.added else
                                                                  "before_after_with_missing.png"))))
            if "gain_drift" in a.effects and d.spectral is not None:
                plots.append(str(P.plot_spectral(d.spectral, out / f"spectral_residuals_{tag}.png", null=False)))
    if args.json:
        print(json.dumps(_clean(json_report(d, plots)), indent=2))
    else:
        print(text_report(d, plots), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
