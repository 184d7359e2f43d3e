"""``radseek replay DATASET``: re-run the estimate on a recorded flight, dwell by dwell, as in the air.

By default (``--method inflight``) it runs the mission's own in-flight estimate (``estimator.inflight``:
pooling, warm start from the previous estimate, wall shadow test, sigma) on the frames recorded up to
the end of each dwell, from the dwell the mission first estimated at (the end of exploration: read from
``mission_log.jsonl`` beside ``frames.csv`` when the flight wrote one, else ``--from-dwell``, else every
dwell), so on a recorded flight it reproduces the estimates the mission flew with. ``--method NAME``
instead fits another localizer (``sphere``, ``pf``, ``multi-pf``, ``gp``, ``mle``) afresh after every dwell.
A team run's ``dataset/`` (one folder per vehicle) replays as the team's flight: every vehicle's frames,
dwell by dwell in time order. The table shows how the estimate and its 1-sigma ellipse evolved, and its
error when ``truth.json`` exists.
``--plot FILE`` draws error and sigma against dwell number; ``--json`` prints the rows. Works on any
dataset in the shared format, recorded by radseek or not.

``radseek replay OUT/flight.mcap`` (a path ending in ``.mcap``: the MCAP log ``radseek run`` records)
replays from the recorded topics instead: the frames are rebuilt from ``detector/histogram``, ``pose``
and ``mission/state`` exactly as the mission's recorder made them (``radseek_io/mcap_frames.py``), the first
dwell comes from the first recorded ``estimate``, and the scenario from ``--scenario`` or the run's
``dataset/scenario.json`` (else ``scenario.json``) beside the file; ``truth.json`` from the same place
when it exists.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

INFLIGHT = "inflight"


def replay(dataset, method: str = INFLIGHT, settings: dict | None = None, first_dwell: int = 1,
           localizer: str | None = None) -> list[dict]:
    """One row per dwell: the estimate from the frames recorded up to the end of that dwell.

    ``method`` ``inflight`` runs :class:`estimator.inflight.InflightEstimator` (with the mission's
    ``localizer``, default mle; ``settings`` update its localizer settings) from dwell count ``first_dwell``
    on, as the mission did; any other name fits that localizer with ``settings`` afresh after every dwell.
    Rows: ``dwells`` (count), ``dwell`` (index),
    ``t``, ``x``, ``y``, ``cps_at_1m``, ``background_cps``, ``sigma_m`` (``estimator.inflight.sigma_m``),
    ``sigma_local_m`` (the fit's own curvature: ``sigma_m`` is it misfit-scaled and covering the likelihood's
    other modes, ``estimator.inflight.honest_covariance``), ``misfit_factor``, ``other_mode``,
    ``p_value`` (goodness of fit, nan if the localizer has none), ``background_excess_z`` and
    ``strength_order_z`` (in-flight only: ``estimator.inflight``'s record), ``error_m`` and ``error_sigmas`` (how many
    1-sigmas outside the ellipse the error lies) with truth; ``error`` instead when there is no estimate.
    """
    from estimator.inflight import (
        DEFAULT_LOCALIZER,
        DEFAULT_SETTINGS,
        InflightEstimator,
        error_sigmas,
        honest_covariance,
        repair_covariance,
        sigma_m,
    )
    from estimator.localizers.base import make_localizer
    from estimator.modes import misfit_factor

    f = dataset.frames
    inflight = InflightEstimator(dataset.scenario, localizer or DEFAULT_LOCALIZER,
                                 {**DEFAULT_SETTINGS, **(settings or {})}) if method == INFLIGHT else None
    rows = []
    dwells = [int(d) for d in np.unique(f.dwell[f.dwell >= 0])]
    ends = [float(f.t[f.dwell == d].max()) for d in dwells]  # a team's frames are vehicle by vehicle: by time
    for k, (d, end) in enumerate(sorted(zip(dwells, ends, strict=True), key=lambda de: (de[1], de[0]))):
        if k + 1 < first_dwell:
            continue
        upto = f.select(f.t <= end + 1e-9)
        row = {"dwells": k + 1, "dwell": d, "t": end}
        if inflight is not None:
            est = inflight.update(upto, dwell=k + 1)
            if est is None:
                rows.append({**row, "error": "no estimate (too few frames, or the fit failed)"})
                continue
            s, cov = est, est["covariance"]
            row.update({key: est[key] for key in ("x", "y", "cps_at_1m", "background_cps", "sigma_m", "sigma_local_m",
                                                  "misfit_factor", "other_mode", "effects", "converged", "p_value",
                                                  "background_excess_z", "strength_order_z")})
        else:
            loc = make_localizer(method, **(settings or {}))
            try:
                loc.fit(upto, dataset.scenario)
            except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
                rows.append({**row, "error": str(exc)})
                continue
            s = loc.sources_[0]
            info = getattr(loc, "info_", {})
            converged = bool(info.get("converged", True))
            # the same honesty as in flight: misfit-scaled, covering the likelihood's other modes
            local = repair_covariance(np.asarray(loc.covariance_, dtype=float)[:4, :4]) \
                if np.isfinite(np.asarray(loc.covariance_, dtype=float)[:2, :2]).all() else np.full((2, 2), np.nan)
            phi = misfit_factor(info.get("deviance_per_dof"))
            effects = tuple(getattr(loc, "effects", ()) or ())
            cov, other = honest_covariance(dataset.scenario, upto, {**s, "params": dict(info.get("values", {}))},
                                           local * phi, converged and "second_source" not in effects, phi)
            row.update({"x": s["x"], "y": s["y"], "cps_at_1m": s["cps_at_1m"], "background_cps": float(loc.background_),
                        "sigma_m": sigma_m(cov, converged), "sigma_local_m": sigma_m(local, converged),
                        "misfit_factor": phi, "other_mode": other, "p_value": float(info.get("p_value", math.nan))})
        if dataset.truth is not None:
            tr = dataset.truth.sources[0]
            row["error_m"] = math.hypot(s["x"] - tr.x, s["y"] - tr.y)
            # an untrustworthy estimate (sigma inf) claims no ellipse, so no error lies outside it
            row["error_sigmas"] = error_sigmas(cov, s["x"] - tr.x, s["y"] - tr.y) \
                if math.isfinite(row["sigma_m"]) else 0.0
        rows.append(row)
    return rows


def outside_warning(rows: list[dict]) -> str | None:
    """The warning for the dwells whose error vs truth lies more than ``ERROR_SIGMAS_FLAG`` 1-sigmas outside
    their ellipse (an error the reported uncertainty does not allow), else None."""
    from estimator.inflight import ERROR_SIGMAS_FLAG

    bad = [r for r in rows if r.get("error_sigmas", 0.0) > ERROR_SIGMAS_FLAG]
    if not bad:
        return None
    worst = max(bad, key=lambda r: r["error_sigmas"])
    return (f"at {len(bad)} of {len(rows)} dwells the error vs truth is more than {ERROR_SIGMAS_FLAG:.1f} sigma "
            f"outside the reported ellipse (dwells {', '.join(str(r['dwells']) for r in bad)}; worst: dwell "
            f"{worst['dwells']}, error {worst['error_m']:.3f} m at 1-sigma {worst['sigma_m']:.3f} m, "
            f"{worst['error_sigmas']:.1f} sigma): a bias the model does not know of (an unmodelled effect, "
            f"see `radseek diagnose`), or a mode the fit sits in wrongly")


def flown_first_dwell(path: str | Path) -> int | None:
    """The dwell count at which the mission that recorded ``path`` first had an estimate (from its
    ``mission_log.jsonl``), or None when the dataset has no such log."""
    log = Path(path) / "mission_log.jsonl"
    if not log.is_file():
        return None
    for line in log.read_text().splitlines():
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:
            continue
        est = entry.get("estimate") if isinstance(entry, dict) else None
        if entry.get("event") == "decision" and isinstance(est, dict) and "dwell" in est:
            return int(est["dwell"])
    return None


def team_folders(path: str | Path) -> list[Path]:
    """The vehicles' dataset folders of a team run's ``dataset/`` (``uav0``, ``uav1``, ... by team index), or []
    when ``path`` is one dataset."""
    path = Path(path)
    if not path.is_dir() or (path / "frames.csv").exists():
        return []
    inner = [p for p in path.iterdir() if p.is_dir() and (p / "frames.csv").exists()]
    return sorted(inner, key=lambda p: (len(p.name), p.name))  # uav2 before uav10


def read_team(path: str | Path):
    """A team run's flight as one dataset (``mission.team.team_frames``: every vehicle's frames, team-unique
    dwell indices, the vehicle and odometry walk of each frame), and the dwell count of the team's first
    estimate (None: no mission log says)."""
    from mission.team import team_frames
    from radseek.dataset import Dataset
    from radseek_io.truth import read_dataset_with_truth

    folders = team_folders(path)
    sets = [read_dataset_with_truth(p) for p in folders]
    frames = team_frames([d.frames for d in sets])
    firsts = [f for f in (flown_first_dwell(p) for p in folders) if f is not None]
    truth = next((d.truth for d in sets if d.truth is not None), None)
    return Dataset(frames=frames, scenario=sets[0].scenario, truth=truth, path=Path(path)), min(firsts, default=None)


def _read_mcap(path: str, scenario: str | None):
    """The flight in a run's MCAP log as a dataset, and the dwell count of its first estimate (None: none
    recorded). DatasetError or McapFrameError (both name the file) when it cannot be read."""
    from radseek.dataset import DatasetError
    from radseek_io.dataset import read_scenario
    from radseek_io.mcap_frames import beside, read_flight
    from radseek_io.truth import read_truth

    scenario_file = Path(scenario) if scenario else beside(path, "scenario.json")
    if scenario_file is None:
        folder = Path(path).parent
        raise DatasetError(f"{path}: no scenario.json beside it (looked for {folder / 'dataset' / 'scenario.json'} "
                           f"and {folder / 'scenario.json'}): give the flight's --scenario")
    sc = read_scenario(scenario_file)
    truth_file = beside(path, "truth.json")
    flight = read_flight(path, sc)
    dropped = ", ".join(f"{n} {topic}" for topic, n in flight.dropped.items())
    usable = len(flight.frames)
    print(f"radseek replay: {len(flight.records)} frames rebuilt from {path} ({usable} usable"
          f"{'; dropped invalid: ' + dropped if dropped else ''}), scenario {scenario_file}", file=sys.stderr)
    return flight.dataset(sc, read_truth(truth_file) if truth_file else None), flight.first_dwell()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="radseek replay", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dataset", help="dataset directory (frames.csv, scenario.json[, truth.json]), or a run's MCAP "
                                   "log (a path ending in .mcap, e.g. OUT/flight.mcap)")
    p.add_argument("--scenario", metavar="FILE",
                   help="MCAP replay: the flight's scenario.json (default: dataset/scenario.json, else scenario.json, "
                        "beside the .mcap file)")
    p.add_argument("--method", default=INFLIGHT,
                   help="inflight (the mission's in-flight estimate, default) or a localizer fitted afresh after "
                        "every dwell: sphere, pf, multi-pf, gp, mle")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="localizer setting, e.g. --set n_starts=4 (JSON values)")
    p.add_argument("--localizer", default=None,
                   help="inflight: the localizer the mission flew with (mission --localizer; default mle)")
    p.add_argument("--from-dwell", type=int, default=None, metavar="N",
                   help="inflight: the dwell count the mission first estimated at (default: from the flight's "
                        "mission_log.jsonl, or an MCAP log's first estimate, else 1)")
    p.add_argument("--plot", help="write error/sigma against dwell number to this PNG")
    p.add_argument("--json", action="store_true", help="print the rows as JSON")
    args = p.parse_args(argv)

    from estimator.inflight import ERROR_SIGMAS_FLAG, excess_warning, gof_warning
    from radseek.dataset import DatasetError
    from radseek_io.mcap_frames import McapFrameError
    from radseek_io.truth import read_dataset_with_truth

    from_mcap = args.dataset.endswith(".mcap")
    if not from_mcap:  # a run's output folder names its dataset/ (a team's: one folder per vehicle, joint)
        from radseek_io.dataset import run_dataset

        args.dataset = str(run_dataset(args.dataset))
    if args.scenario and not from_mcap:
        p.error("--scenario is for an MCAP log (a path ending in .mcap); a dataset holds its own scenario.json")
    try:
        team = [] if from_mcap else team_folders(args.dataset)
        if from_mcap:
            ds, mcap_first = _read_mcap(args.dataset, args.scenario)
        elif team:
            ds, mcap_first = read_team(args.dataset)
            print(f"radseek replay: a team's flight: {', '.join(p.name for p in team)} ({len(ds.frames)} frames)",
                  file=sys.stderr)
        else:
            ds, mcap_first = read_dataset_with_truth(args.dataset), None
    except (DatasetError, McapFrameError) as exc:  # both name the file
        print(f"radseek replay: {exc}", file=sys.stderr)
        return 2
    settings = {}
    for item in args.set:
        key, _, value = item.partition("=")
        try:
            settings[key] = json.loads(value)
        except json.JSONDecodeError:
            settings[key] = value
    try:
        flown = (mcap_first if from_mcap or team else flown_first_dwell(args.dataset)) \
            if args.method == INFLIGHT else None
        first = args.from_dwell if args.from_dwell is not None else flown or 1
        rows = replay(ds, args.method, settings, first_dwell=first, localizer=args.localizer)
    except ValueError as exc:
        print(f"radseek replay: {exc}", file=sys.stderr)
        return 2
    if not rows:
        print(f"radseek replay: {args.dataset} has no dwell points (dwell column is -1 throughout)", file=sys.stderr)
        return 1
    # the last estimate is the one the flight ended with: say so when its model does not fit the data
    last = next((r for r in reversed(rows) if "error" not in r), None)
    warning = gof_warning(last.get("p_value"), args.dataset) if last else None
    excess = excess_warning(last, ds.scenario.background_cps, args.dataset) if last and args.method == INFLIGHT \
        else None
    outside = outside_warning(rows)
    if args.json:
        print(json.dumps(rows, indent=2))
        if warning:
            print(f"radseek replay: warning: {warning}", file=sys.stderr)
        if outside:
            print(f"radseek replay: warning: {outside}", file=sys.stderr)
        if excess:
            print(f"radseek replay: warning: {excess}", file=sys.stderr)
    else:
        truth = any("error_m" in r for r in rows)
        print(f"{'dwells':>6} {'t (s)':>8} {'x (m)':>7} {'y (m)':>7} {'cps@1m':>8} {'sigma (m)':>9} {'error (m)':>9} "
              f"{'p (fit)':>8}" + (f" {'err/sigma':>9}" if truth else ""))
        for r in rows:
            if "error" in r:
                print(f"{r['dwells']:>6} {r['t']:>8.1f}  fit failed: {r['error']}")
                continue
            err = f"{r['error_m']:9.3f}" if "error_m" in r else f"{'-':>9}"
            line = (f"{r['dwells']:>6} {r['t']:>8.1f} {r['x']:7.2f} {r['y']:7.2f} {r['cps_at_1m']:8.0f} "
                    f"{r['sigma_m']:9.3f} {err} {r.get('p_value', math.nan):8.2g}")
            if "error_sigmas" in r:
                line += f" {r['error_sigmas']:9.1f}" + (" !" if r["error_sigmas"] > ERROR_SIGMAS_FLAG else "")
            if r.get("other_mode"):
                o = r["other_mode"]
                line += f"  (another mode at ({o['x']:.2f}, {o['y']:.2f}) holds {o['share']:.0%})"
            print(line)
        if warning:
            print(f"THE MODEL MISSES SOMETHING HERE: {warning}")
        if outside:
            print(f"THE UNCERTAINTY IS NOT HONEST HERE: {outside}")
        if excess:
            print(f"THE BACKGROUND IS TOO HIGH HERE: {excess}")
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        ok = [r for r in rows if "sigma_m" in r]
        fig, ax = plt.subplots(figsize=(6, 4))
        ax.semilogy([r["dwells"] for r in ok], [max(r["sigma_m"], 1e-4) for r in ok], "s--", label="1-sigma (m)")
        if ok and "error_m" in ok[0]:
            ax.semilogy([r["dwells"] for r in ok], [max(r["error_m"], 1e-4) for r in ok], "o-", label="error (m)")
        ax.set_xlabel("dwell points")
        ax.set_title(f"replay of {ds.name} with {args.method}")
        ax.legend()
        fig.tight_layout()
        fig.savefig(args.plot, dpi=110)
        print(f"plot: {args.plot}", file=sys.stderr)
    return 0
