"""``radseek replay DATASET``: re-run an estimator on a recorded flight, dwell by dwell, as in the air.

After each dwell point the chosen localizer (default ``mle``, the mission's) is fitted on every frame
recorded up to the end of that dwell; the table shows how the estimate and its 1-sigma ellipse evolved,
and its error when ``truth.json`` exists. ``--plot FILE`` draws error and sigma against dwell number;
``--json`` prints the rows. Works on any dataset in the shared format, recorded by radseek or not.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np


def replay(dataset, method: str = "mle", settings: dict | None = None) -> list[dict]:
    from estimator.localizers.base import make_localizer

    f = dataset.frames
    rows = []
    dwells = [int(d) for d in np.unique(f.dwell[f.dwell >= 0])]
    ends = [int(np.flatnonzero(f.dwell == d).max()) for d in dwells]
    for k, (d, end) in enumerate(sorted(zip(dwells, ends, strict=True), key=lambda de: de[1])):
        upto = f.select(np.arange(len(f)) <= end)
        loc = make_localizer(method, **(settings or {}))
        try:
            loc.fit(upto, dataset.scenario)
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            rows.append({"dwells": k + 1, "dwell": d, "t": float(upto.t[-1]), "error": str(exc)})
            continue
        s = loc.sources_[0]
        cov = np.asarray(loc.covariance_, dtype=float)[:2, :2]
        sigma = float(math.sqrt(max(np.linalg.eigvalsh(np.nan_to_num(cov)).max(), 0.0)))
        row = {"dwells": k + 1, "dwell": d, "t": float(upto.t[-1]), "x": s["x"], "y": s["y"],
               "cps_at_1m": s["cps_at_1m"], "background_cps": float(loc.background_), "sigma_m": sigma}
        if dataset.truth is not None:
            tr = dataset.truth.sources[0]
            row["error_m"] = math.hypot(s["x"] - tr.x, s["y"] - tr.y)
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="radseek replay", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dataset", help="dataset directory (frames.csv, scenario.json[, truth.json])")
    p.add_argument("--method", default="mle", help="localizer: sphere, pf, multi-pf, gp, mle (default mle)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="localizer setting, e.g. --set n_starts=4 (JSON values)")
    p.add_argument("--plot", help="write error/sigma against dwell number to this PNG")
    p.add_argument("--json", action="store_true", help="print the rows as JSON")
    args = p.parse_args(argv)

    from radseek.dataset import DatasetError, read_dataset

    try:
        ds = read_dataset(args.dataset)
    except DatasetError as exc:
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
        rows = replay(ds, args.method, settings)
    except ValueError as exc:
        print(f"radseek replay: {exc}", file=sys.stderr)
        return 2
    if not rows:
        print(f"radseek replay: {args.dataset} has no dwell points (dwell column is -1 throughout)", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        print(f"{'dwells':>6} {'t (s)':>8} {'x (m)':>7} {'y (m)':>7} {'cps@1m':>8} {'sigma (m)':>9} {'error (m)':>9}")
        for r in rows:
            if "error" in r:
                print(f"{r['dwells']:>6} {r['t']:>8.1f}  fit failed: {r['error']}")
                continue
            err = f"{r['error_m']:9.3f}" if "error_m" in r else f"{'-':>9}"
            print(f"{r['dwells']:>6} {r['t']:>8.1f} {r['x']:7.2f} {r['y']:7.2f} {r['cps_at_1m']:8.0f} "
                  f"{r['sigma_m']:9.3f} {err}")
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
