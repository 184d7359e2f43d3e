"""``radseek localize DATASET --method NAME [--json]``: estimate source position and strength from a dataset.

Prints the estimate (position, ``cps_at_1m``, background), its uncertainty (1-sigma from the method's
covariance, and the Cramér-Rao bound when the method has one) and, when the dataset has a truth.json,
the error. The truth is read here, after fitting, and never handed to the localizer.

Examples::

    radseek localize /work/shared/datasets/lattice-clean --method mle
    radseek localize two-sources/ --method mle --effects second_source --json
    radseek localize lattice-wall/ --method multi-pf --set wall_mu_per_m=3.0 --set n_particles=20000
"""

from __future__ import annotations

import argparse
import inspect
import json
import math
import sys
import threading
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

# one goodness-of-fit threshold for localize, run and replay; as in flight, fewer than MIN_FRAMES are not fitted
from estimator.diagnose.verdict import source_reading
from estimator.inflight import GOOD_FIT_P, MIN_FRAMES
from estimator.localizers import LOCALIZERS, make_localizer
from estimator.localizers.base import localizer_class
from radseek.dataset import DatasetError
from radseek_io.dataset import DatasetWarning, check_walls_disjoint, read_scenario, run_dataset, stderr_progress
from radseek_io.truth import read_dataset_with_truth
from reporting.truth_errors import match_errors

__all__ = ["main", "parse_settings", "check_settings", "read_with_warnings"]

#: a flight longer than this is fitted on pooled frames (consecutive frames of one dwell or transit run
#: summed): a 1.4 M-frame flight would otherwise need several GB in the localizers' start-point grids
MAX_FRAMES = 100_000

#: print "still fitting" to stderr this often while a fit runs (a 1.4 M-frame flight takes minutes)
HEARTBEAT_S = 10.0


def parse_settings(items: list[str]) -> dict[str, Any]:
    """``key=value`` pairs; values parsed as JSON when possible (numbers, lists, true/null), else strings."""
    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise ValueError(f"--set expects key=value, got {item!r}")
        k, v = item.split("=", 1)
        try:
            out[k.strip()] = json.loads(v)
        except json.JSONDecodeError:
            out[k.strip()] = v
    return out


def check_settings(method: str, settings: dict[str, Any]) -> None:
    """ValueError naming the setting when a value's type does not match the localizer's default (``--set
    n_starts=abc`` would otherwise fail deep inside the fit with a TypeError)."""
    params = inspect.signature(localizer_class(method).__init__).parameters
    for key, value in settings.items():
        p = params.get(key)
        if p is None or p.default is inspect.Parameter.empty or p.default is None:
            continue  # unknown settings are make_localizer's to report; None defaults take anything
        d = p.default
        if isinstance(d, bool):
            ok, want = isinstance(value, bool), "true or false"
        elif isinstance(d, int):
            ok, want = isinstance(value, int) and not isinstance(value, bool), "an integer"
            if ok and key.startswith("n_") and value < 1:
                ok, want = False, "an integer >= 1"
        elif isinstance(d, float):
            ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
            want = "a finite number"
        elif isinstance(d, str):
            ok, want = isinstance(value, str), "a string"
        elif isinstance(d, tuple | list):
            ok = isinstance(value, list) and all(isinstance(v, str | int | float) for v in value)
            want = 'a JSON list (e.g. ["dead_time"])'
        else:
            continue
        if not ok:
            raise ValueError(f"--set {key}: expected {want}, got {value!r}")


@contextmanager
def read_with_warnings(prog: str) -> Iterator[None]:
    """Print the reader's DatasetWarnings (e.g. a skipped truncated last row) as ``prog: warning: ...``."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DatasetWarning)
        try:
            yield
        finally:
            for w in caught:
                if issubclass(w.category, DatasetWarning):
                    print(f"{prog}: warning: {w.message}", file=sys.stderr)
                else:
                    warnings.showwarning(w.message, w.category, w.filename, w.lineno)


def read_for_cli(prog: str, path: str | Path, quiet: bool = False, min_frames: int = MIN_FRAMES,
                 needed_for: str = "to fit a source's position and strength and the background"):
    """The dataset at ``path`` for command ``prog`` (progress and reader warnings on stderr), or None after
    printing one line on stderr: the reader's error (which names file, row and column, or key), walls that
    overlap (``check_walls_disjoint``: every model here attenuates through each wall, so an overlap would count
    twice), or fewer than ``min_frames`` usable frames (the reader keeps only rows with a finite pose and
    duration > 0; a truncated last row is skipped), with what they are ``needed_for``."""
    path = run_dataset(path)  # a run's output folder names its dataset/
    scenario_file = path / "scenario.json"
    try:
        with read_with_warnings(prog):
            if scenario_file.is_file():  # walls first: a long flight's frames take minutes to read
                check_walls_disjoint(read_scenario(scenario_file), scenario_file)
            progress = None if quiet else stderr_progress(f"{prog}: reading frames.csv")
            ds = read_dataset_with_truth(path, progress=progress)  # the truth for the error report only
    except DatasetError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return None
    if len(ds.frames) < min_frames:
        print(f"{prog}: {ds.path / 'frames.csv'}: only {len(ds.frames)} usable frame"
              f"{'' if len(ds.frames) == 1 else 's'} (at least {min_frames} are needed {needed_for})",
              file=sys.stderr)
        return None
    return ds


@contextmanager
def heartbeat(message: str, every_s: float = HEARTBEAT_S, quiet: bool = False) -> Iterator[None]:
    """While the block runs, print ``message (N s)`` to stderr every ``every_s``: long fits show progress."""
    stop = threading.Event()
    t0 = time.monotonic()

    def beat() -> None:
        while not stop.wait(every_s):
            print(f"{message} ({time.monotonic() - t0:.0f} s)", file=sys.stderr, flush=True)

    thread = None if quiet else threading.Thread(target=beat, daemon=True)
    if thread is not None:
        thread.start()
    try:
        yield
    finally:
        stop.set()
        if thread is not None:
            thread.join(1.0)


def _build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="radseek localize", description=__doc__.split("\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="methods: " + ", ".join(LOCALIZERS))
    p.add_argument("dataset", help="dataset directory (frames.csv, scenario.json, optional truth.json)")
    p.add_argument("--method", "-m", default="mle", choices=list(LOCALIZERS), help="localizer (default: mle)")
    p.add_argument("--effects", default="",
                   help="comma-separated model effects for mle (e.g. dead_time,wall_attenuation)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="localizer setting, repeatable (e.g. --set n_particles=20000)")
    p.add_argument("--json", action="store_true", help="print a machine-readable JSON result")
    p.add_argument("--quiet", action="store_true", help="no progress messages on stderr")
    p.add_argument("--max-frames", type=int, default=MAX_FRAMES, metavar="N",
                   help=f"pool consecutive frames of one dwell or transit run so at most N are fitted "
                        f"(default {MAX_FRAMES}; memory grows with the frames fitted)")
    return p


def _std(cov: np.ndarray | None, i: int) -> list[float] | None:
    if cov is None:
        return None
    c = np.asarray(cov)
    return [float(np.sqrt(max(c[4 * i + k, 4 * i + k], 0.0))) for k in range(4)]


def hold_to_the_bound(loc: Any, scenario: Any, frames: Any, result: dict[str, Any], method: str) -> list[str]:
    """Every method's one-source estimate checked as the MLE checks its own (``estimator.mle.check_estimate``):
    a reported 1-sigma below the Cramér-Rao bound at the flown poses is raised to the bound (the method's own kept
    as ``std_method``), and a method that reports no goodness of fit gets one at its estimate under the common
    count model. Where the frames declare pose errors (odometry drift) the bound is the pose-aware one
    (``pose_aware_crlb``, the MLE's own floor): with drift no estimate can place the source better than the poses
    allow. Returns the warnings to print."""
    from estimator.localizers.mle import pose_aware_crlb
    from estimator.mle import check_estimate
    from estimator.model import MeasurementModel

    if len(loc.sources_) != 1 or not result.get("std") or result["std"][0] is None:
        return []
    try:
        model = MeasurementModel(scenario, effects=tuple(getattr(loc, "effects", ()) or ()))
        s = loc.sources_[0]
        theta = {"x": s["x"], "y": s["y"], "z": s["z"], "cps_at_1m": s["cps_at_1m"],
                 "background_cps": float(loc.background_)}
        theta = {k: float(v) for k, v in theta.items() if k in model.param_names}
        chk = check_estimate(model, theta, frames)
        drifting = bool(np.any(np.asarray(frames.pose_variances) > 0))
        hybrid = pose_aware_crlb(model, theta, frames) if drifting else None
    except (ValueError, KeyError, TypeError, np.linalg.LinAlgError):
        return []  # a model the common count model cannot express (say a multi-source cloud): nothing to hold to
    bound = {nm: float(np.sqrt(max(chk.crlb[i, i], 0.0))) for i, nm in enumerate(chk.names)}
    floor = dict(bound)
    if hybrid is not None:  # same parameter order (the model's free names); never below the exact-pose bound
        floor = {nm: max(b, float(np.sqrt(max(hybrid[i, i], 0.0)))) for i, (nm, b) in enumerate(bound.items())}
        if getattr(loc, "crlb_pose_", None) is None:  # the line "bound with pose errors and drift" is this one
            result["bound_m"] = [float(np.hypot(floor.get("x", math.nan), floor.get("y", math.nan)))]
    sd = list(result["std"][0])
    raised = []
    for j, nm in ((0, "x"), (1, "y"), (3, "cps_at_1m")):
        b = floor.get(nm, math.nan)
        if math.isfinite(b) and math.isfinite(sd[j]) and sd[j] < b:
            raised.append(f"{nm} ±{sd[j]:.3g} -> ±{b:.3g}")
            sd[j] = b
    bstd = getattr(loc, "background_std_", None)
    b = floor.get("background_cps", math.nan)
    if bstd is not None and math.isfinite(b) and bstd < b:
        raised.append(f"background_cps ±{bstd:.3g} -> ±{b:.3g}")
        result["background_std"] = b
    out = []
    if raised:
        result["std_method"] = [list(result["std"][0])]
        result["std"] = [sd]
        where = "the flown poses with their declared drift" if hybrid is not None else "the flown poses"
        out.append(f"{method}'s own spread is below the Cramér-Rao bound at {where} ({', '.join(raised)}): "
                   "the ± printed is the bound, the least any unbiased estimate from these counts can have")
    if result.get("crlb_std") is None:
        result["crlb_std"] = [[bound.get("x", math.nan), bound.get("y", math.nan), bound.get("z", math.nan),
                               bound.get("cps_at_1m", math.nan)]]
    info = result.setdefault("info", {})
    if "p_value" not in info:
        info.update({"deviance_per_dof": chk.deviance_per_dof, "p_value": chk.p_value,
                     "fit_check": "the common count model at this estimate, pose offsets profiled"})
    return out


def main(argv: list[str] | None = None) -> int:
    args = _build_parser().parse_args(argv)
    try:
        settings = parse_settings(args.set)
        if args.effects:
            settings["effects"] = [e.strip() for e in args.effects.split(",") if e.strip()]
        check_settings(args.method, settings)
        loc = make_localizer(args.method, **settings)
    except (ValueError, TypeError) as exc:
        print(f"radseek localize: {exc}", file=sys.stderr)
        return 2
    ds = read_for_cli("radseek localize", args.dataset, args.quiet)
    if ds is None:
        return 2
    effects = list(getattr(loc, "effects", None) or ())
    if "wall_attenuation" in effects and not ds.scenario.walls:
        print(f"radseek localize: effect wall_attenuation needs walls, but {ds.path}/scenario.json lists none "
              "(key 'walls'); drop the effect or map the walls", file=sys.stderr)
        return 2
    frames = ds.frames
    if args.max_frames < 1:
        print("radseek localize: --max-frames must be >= 1", file=sys.stderr)
        return 2
    if len(frames) > args.max_frames:
        from estimator.mle import pooled

        size = -(-len(frames) // args.max_frames)
        frames = pooled(frames, size)
        if not args.quiet:
            print(f"radseek localize: {len(ds.frames)} frames pooled {size} at a time into {len(frames)} "
                  f"(--max-frames {args.max_frames})", file=sys.stderr)
    t0 = time.perf_counter()
    try:
        with heartbeat(f"radseek localize: fitting {args.method} on {len(frames)} frames", quiet=args.quiet):
            loc.fit(frames, ds.scenario)  # frames and scenario only: the truth stays here
    except (ValueError, TypeError, ArithmeticError, np.linalg.LinAlgError) as exc:
        print(f"radseek localize: {args.method} failed on {ds.name}: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    elapsed = time.perf_counter() - t0
    result = loc.result()
    result["dataset"] = str(ds.path)
    result["elapsed_s"] = elapsed
    result["std"] = [_std(loc.covariance_, i) for i in range(len(loc.sources_))]
    result["crlb_std"] = [_std(loc.crlb_, i) for i in range(len(loc.sources_))] if loc.crlb_ is not None else None
    result["frames_fitted"] = len(frames)
    bound = getattr(loc, "crlb_pose_", None)
    bound = bound if bound is not None else loc.crlb_
    # the pose-and-drift-aware bound on the horizontal position: rms radial error an unbiased fit can reach
    result["bound_m"] = ([float(np.sqrt(max(np.trace(np.asarray(bound)[4 * i:4 * i + 2, 4 * i:4 * i + 2]), 0.0)))
                          for i in range(len(loc.sources_))] if bound is not None else None)
    if ds.truth is not None:
        result["error"] = match_errors(loc.sources_, ds.truth)
    held = hold_to_the_bound(loc, ds.scenario, frames, result, args.method)
    pinned = result["pinned_at_bound"]
    result["warnings"] = held + [
        f"source {i + 1}: {k} = {loc.sources_[i][k]:.3f} m is pinned at the bounds' {side} (scenario.json "
        f"'bounds'); it is where the search box stopped the fit, not a measurement: widen the bounds"
        for i, p in enumerate(pinned) for k, side in p.items()]
    p_fit = result.get("info", {}).get("p_value")
    if p_fit is not None and p_fit < GOOD_FIT_P:
        result["warnings"].append(
            f"goodness of fit p = {p_fit:.2g} < {GOOD_FIT_P:g}: the model misses something here, so the "
            f"estimate and its ± are not to be trusted; run `radseek diagnose {ds.path}`")
    for w in result["warnings"]:
        print(f"radseek localize: warning: {w}", file=sys.stderr)
    if args.json:
        print(json.dumps(result, indent=2, default=float))
        return 0
    print(f"{ds.name}: method {args.method} ({elapsed:.2f} s, {len(frames)} frames"
          + (f" pooled from {len(ds.frames)})" if len(frames) != len(ds.frames) else ")"))
    for i, s in enumerate(loc.sources_):
        sd = result["std"][i]
        print(f"  source {i + 1}: x = {s['x']:.3f} ± {sd[0]:.3f} m, y = {s['y']:.3f} ± {sd[1]:.3f} m, "
              f"z = {s['z']:.2f} m, cps_at_1m = {s['cps_at_1m']:.0f} ± {sd[3]:.0f}")
        if pinned[i]:
            where = ", ".join(f"{k} at bounds {side}" for k, side in pinned[i].items())
            print(f"            PINNED AT A BOUND ({where}): not a measurement; widen scenario.json 'bounds'")
        if (plain := source_reading(s["cps_at_1m"], sd[3])) is not None:
            print(f"            {plain}")
        if result["crlb_std"]:
            cr = result["crlb_std"][i]
            print(f"            CRLB 1-sigma: x {cr[0]:.3f} m, y {cr[1]:.3f} m, cps_at_1m {cr[3]:.0f}")
        if result["bound_m"]:
            print(f"            bound with pose errors and drift (rms horizontal): {result['bound_m'][i]:.3f} m")
    bstd = result.get("background_std", getattr(loc, "background_std_", None))
    print(f"  background: {loc.background_:.1f} cps" + (f" ± {bstd:.1f}" if bstd else ""))
    info = result.get("info", {})
    if "deviance_per_dof" in info:
        print(f"  fit: deviance/dof = {info['deviance_per_dof']:.3f}, p = {info['p_value']:.3g}")
        if info["p_value"] < GOOD_FIT_P:
            print(f"  THE MODEL MISSES SOMETHING HERE (p < {GOOD_FIT_P:g}): the ± above assume a model that does "
                  f"not fit; run `radseek diagnose {ds.path}`")
    for j, e in enumerate(result.get("error", [])):
        if e["position_error_m"] is None:
            print(f"  truth source {j + 1} ({e['true_x']:.2f}, {e['true_y']:.2f}): not found")
        else:
            print(f"  error vs truth source {j + 1}: {e['position_error_m']:.3f} m horizontal, "
                  f"intensity {100 * e['intensity_error_rel']:+.1f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
