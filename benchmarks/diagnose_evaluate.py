"""The closing table of ``radseek diagnose``: datasets x (named effect, delta-AIC, deviance/dof before -> after,
source error before -> after), over the shared reference datasets, emulated flights with each effect, and
null flights (no effect: how many false alarms).

    python benchmarks/diagnose_evaluate.py [--shared DIR] [--only shared|effects|null] [--jsonl FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from radseek.dataset import Dataset, read_dataset

SHARED = ["lattice-clean", "lattice-wall", "close-pass-deadtime", "spin-anisotropy", "outdoor-air", "two-sources"]


def emulated(which: str, null_seeds: tuple[int, ...] = (11, 12, 13), names: list[str] | None = None
             ) -> Iterator[tuple[str, Callable[[], Dataset]]]:
    for name, make in _emulated(which, null_seeds):
        if not names or name in names:
            yield name, make


def _emulated(which: str, null_seeds: tuple[int, ...]) -> Iterator[tuple[str, Callable[[], Dataset]]]:
    from detector_fw_sim.scene import load_scene
    from detector_fw_sim.simulate import simulate_flight

    d = load_scene().without_effects()
    if which == "null":
        for path in ("lattice", "lawnmower", "spin", "close-pass"):
            for seed in null_seeds:
                yield f"null-{path}-{seed}", lambda p=path, s=seed: simulate_flight(d, path=p, seed=s)
        return
    yield "emu-dead_time", lambda: simulate_flight(load_scene("close-pass-deadtime"), path="close-pass", seed=5)
    yield "emu-wall", lambda: simulate_flight(load_scene("lattice-wall"), path="lattice", seed=5)
    yield "emu-anisotropy", lambda: simulate_flight(load_scene("spin-anisotropy"), path="spin", seed=5)
    yield "emu-air", lambda: simulate_flight(load_scene("outdoor"), path="lawnmower", seed=5)
    yield "emu-second_source", lambda: simulate_flight(load_scene("two-source"), path="lattice", seed=5)
    yield "emu-bg_gradient", lambda: simulate_flight(d.with_effect("background_gradient", gx=3.0, gy=-2.0),
                                                     path="lawnmower", seed=5)
    yield "emu-gain_drift", lambda: simulate_flight(d.with_effect("gain_drift", percent_per_min=1.0), path="lattice",
                                                    seed=5)
    yield "emu-pose_drift", lambda: simulate_flight(d.with_effect("pose_drift", vx=0.003, vy=-0.002), path="lattice",
                                                    seed=5)
    yield "emu-anisotropy+bg_gradient", lambda: simulate_flight(
        d.with_effect("anisotropy", fraction=0.5, half_angle_deg=30.0).with_effect("background_gradient", gx=3.0,
                                                                                  gy=-2.0), path="lawnmower", seed=5)
    yield "emu-second_source+bg_gradient", lambda: simulate_flight(
        load_scene("two-source").with_effect("background_gradient", gx=3.0, gy=-2.0), path="lawnmower", seed=5)
    yield "emu-dead_time+bg_gradient", lambda: simulate_flight(
        load_scene("close-pass-deadtime").with_effect("background_gradient", gx=4.0, gy=-2.0), path="close-pass",
        seed=5)


def row(name: str, ds: Dataset, n_starts: int = 8) -> dict:
    from estimator.diagnose.runner import diagnose

    t0 = time.perf_counter()
    d = diagnose(ds, quiet=True, n_starts=n_starts)
    first = d.selection.first
    named = d.selection.missing
    chosen = [st.candidates[0] for st in d.selection.steps if st.chosen]
    after = d.after
    spec_b = d.current.spectral_dev_per_dof
    return {
        "dataset": name,
        "truth": sorted(ds.truth.effects) if ds.truth else None,
        "named": named,
        "delta_aic": [round(c.delta_aic, 1) for c in chosen],
        "top": first[0].effect if first else None,
        "top_delta_aic": round(first[0].delta_aic, 1) if first else None,
        "dev_before": round(d.current.gof.deviance_per_dof, 3),
        "dev_after": round(after.gof.deviance_per_dof, 3) if after else None,
        "dev_expected": round((after or d.current).gof.expected_per_dof, 3),
        "dev_sd": round((after or d.current).gof.sd_per_dof, 3),
        "spec_before": round(spec_b, 3),
        "spec_after": round(after.spectral_dev_per_dof, 3) if after else None,
        "err_before": None if d.current.source_error_m is None else round(d.current.source_error_m, 3),
        "err_after": None if not after or after.source_error_m is None else round(after.source_error_m, 3),
        "explains": [c.explains for c in chosen],
        "seconds": round(time.perf_counter() - t0, 1),
    }


def markdown(rows: list[dict]) -> str:
    lines = ["| dataset | truth | named (delta-AIC) | deviance/dof before -> after (expected +- sd) | "
             "source error before -> after [m] | explains | s |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        named = ", ".join(f"{e} ({a})" for e, a in zip(r["named"], r["delta_aic"], strict=True)) or \
            f"adequate (best: {r['top']}, {r['top_delta_aic']})"
        dev = f"{r['dev_before']} -> {r['dev_after'] if r['dev_after'] is not None else '-'} " \
              f"({r['dev_expected']} +- {r['dev_sd']})"
        if "gain_drift" in r["named"]:
            dev += f"; spectral {r['spec_before']} -> {r['spec_after']}"
        err = f"{r['err_before']} -> {r['err_after'] if r['err_after'] is not None else '-'}"
        lines.append(f"| {r['dataset']} | {', '.join(r['truth'] or []) or 'none'} | {named} | {dev} | {err} | "
                     f"{', '.join(r['explains'])} | {r['seconds']} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--shared", type=Path, default=Path(__file__).resolve().parents[3] / "shared" / "datasets")
    p.add_argument("--only", choices=["shared", "effects", "null"], action="append")
    p.add_argument("--jsonl", type=Path, default=None, help="also append one JSON row per dataset here")
    p.add_argument("--starts", type=int, default=8)
    p.add_argument("--null-seeds", type=int, nargs="+", default=[11, 12, 13])
    p.add_argument("--names", nargs="+", default=None, help="only these emulated datasets")
    args = p.parse_args(argv)
    which = args.only or ["shared", "effects", "null"]
    jobs: list[tuple[str, Callable[[], Dataset]]] = []
    if "shared" in which:
        jobs += [(n, lambda n=n: read_dataset(args.shared / n)) for n in SHARED if (args.shared / n).is_dir()]
    if "effects" in which:
        jobs += list(emulated("effects", names=args.names))
    if "null" in which:
        jobs += list(emulated("null", tuple(args.null_seeds), names=args.names))
    rows = []
    for name, make in jobs:
        r = row(name, make(), args.starts)
        rows.append(r)
        print(f"{name}: {r}", file=sys.stderr, flush=True)
        if args.jsonl:
            with args.jsonl.open("a") as fh:
                fh.write(json.dumps(r) + "\n")
    print(markdown(rows))
    nulls = [r for r in rows if r["dataset"].startswith("null-")]
    if nulls:
        print(f"\nnull flights: {sum(bool(r['named']) for r in nulls)} false alarm(s) in {len(nulls)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
