"""``radseek campaign``: many seeded in-process searches as Ray tasks, results as Parquet (docs/campaigns.md).

    radseek campaign --scenes default lattice-wall --strategies active lattice --seeds 250 --out runs/c1
    radseek campaign --config sweep.toml --out runs/c2 --workers 2
    radseek campaign --config sweep.toml --out runs/c2 --address 10.0.0.5:6379   # an existing Ray cluster

Flags override the TOML file's ``[sweep]``. Rerunning the same sweep into the same --out flies only the
flights with no row yet (more --seeds extend it); another sweep's folder is refused unless --force.
"""

from __future__ import annotations

import argparse
import sys

EPILOG = """\
sweep TOML:
  [sweep]
  scenes = ["default", "lattice-wall"]
  strategies = ["active", "lattice"]
  seeds = 250                      # or [0, 5, 9], or {start = 250, stop = 500}
  effects = ["none", "dead_time:tau_s=2e-5"]
  [sweep.params]                   # SearchConfig fields (dotted), odometry.*, flight.speed
  max_dwells = 16
  "dwell.t_max" = [10.0, 15.0]     # a list sweeps
"""


def build_parser() -> argparse.ArgumentParser:
    from mission.search import STRATEGIES

    p = argparse.ArgumentParser(prog="radseek campaign", description=__doc__, epilog=EPILOG,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", help="sweep TOML file ([sweep] and [sweep.params])")
    p.add_argument("--scenes", nargs="+", metavar="SCENE", help="bundled scene names or scene files")
    p.add_argument("--strategies", nargs="+", choices=STRATEGIES, metavar="STRATEGY",
                   help=f"search strategies ({', '.join(STRATEGIES)})")
    p.add_argument("--seeds", metavar="N|A:B|S,S,...",
                   help="seeds: a count (0..N-1), a range A:B, or a comma list (default 10)")
    p.add_argument("--effect", action="append", metavar="NAME[:K=V,...]", dest="effects",
                   help="an effect case (repeatable): none, dead_time, dead_time:tau_s=2e-5, ...")
    p.add_argument("--set", action="append", default=[], metavar="PARAM=V[,V...]", dest="sets",
                   help="a search parameter (dotted SearchConfig field, odometry.*, flight.speed); "
                        "several values sweep it (repeatable)")
    p.add_argument("--out", required=True, help="campaign folder (resumed if it holds this sweep)")
    p.add_argument("--force", action="store_true", help="replace another campaign's outputs in --out")
    p.add_argument("--workers", type=int, help="CPUs of the embedded local Ray (default: all)")
    p.add_argument("--address", metavar="HOST:PORT", help="run on an existing Ray cluster instead")
    p.add_argument("--niceness", type=int, metavar="N",
                   help="nice level of the embedded workers (default Ray's 15: other work on the machine goes first)")
    p.add_argument("--salvage", action="store_true",
                   help="a damaged flights.parquet or part file: keep its readable rows, move it aside "
                        "(NAME.damaged) and fly its other flights again")
    p.add_argument("--retry-failed", action="store_true", help="fly the recorded failed flights again")
    p.add_argument("--no-plots", action="store_true", help="summary.md only")
    p.add_argument("--dry-run", action="store_true", help="print the flights to fly and exit")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress line")
    p.add_argument("--ray-logs", action="store_true", help="show Ray's own log lines")
    return p


def _values(text: str) -> list:
    from launch.campaign import _scalar

    return [_scalar(v.strip()) for v in text.split(",")]


def sweep_from_args(args: argparse.Namespace):
    from launch.campaign import Sweep, seeds_from

    base = Sweep.from_toml(args.config) if args.config else Sweep()
    kw = {"scenes": args.scenes or base.scenes, "strategies": args.strategies or base.strategies,
          "effects": args.effects or base.effects, "seeds": base.seeds, "params": dict(base.params)}
    if args.seeds:
        s = args.seeds
        kw["seeds"] = [int(v) for v in s.split(",")] if "," in s else seeds_from(int(s) if s.isdigit() else s)
    for item in args.sets:
        name, eq, value = item.partition("=")
        if not eq:
            raise ValueError(f"--set {item!r}: expected PARAM=VALUE[,VALUE...]")
        vals = _values(value)
        kw["params"][name.strip()] = vals if len(vals) > 1 else vals[0]
    return Sweep(**kw)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from detector_fw_sim.scene import SceneError
    from launch.campaign import CampaignStopped, DamagedStore, run_campaign
    from radseek_io.outdir import OutputDirError

    try:
        sweep = sweep_from_args(args)
    except (ValueError, OSError) as exc:
        print(f"radseek campaign: {exc}", file=sys.stderr)
        return 2
    if args.dry_run:
        flights = sweep.flights()
        print(f"{len(flights)} flights ({len(sweep.cases())} cases x {len(sweep.seeds)} seeds), "
              f"sweep fingerprint {sweep.fingerprint()}")
        for c in sweep.cases():
            print(f"  {c['scene']} {c['strategy']} {c['effect']} {c['params'] or ''}")
        return 0
    try:
        res = run_campaign(sweep, args.out, workers=args.workers, address=args.address, force=args.force,
                           retry_failed=args.retry_failed, progress=not args.quiet, quiet_ray=not args.ray_logs,
                           plots=not args.no_plots, niceness=args.niceness, salvage=args.salvage)
    except (OutputDirError, SceneError, DamagedStore, OSError) as exc:
        print(f"radseek campaign: {exc}", file=sys.stderr)
        return 2
    except CampaignStopped as exc:
        print(f"\nradseek campaign: {exc}", file=sys.stderr)
        return 130
    for path, problem, kept, aside in res.salvaged:
        print(f"radseek campaign: {path} was damaged ({problem}): kept its {kept} readable rows, moved it to {aside}",
              file=sys.stderr)
    failed = sum(r["status"] != "ok" for r in res.rows)
    print(f"{res.flown} flights flown, {res.skipped} already recorded, {failed} failed; "
          f"{res.wall_s:.0f} s on {res.workers:g} CPUs -> {res.out}/flights.parquet, summary.md")
    print((res.out / "summary.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
