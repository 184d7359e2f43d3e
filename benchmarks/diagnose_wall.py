"""Wall time of whole ``radseek diagnose`` calls as a user runs them (issue 30 item 6: every call <= 60 s of wall
time on 2 idle cores for flights up to 5,000 frames).

Each flight is diagnosed by the command in a process of its own, with its defaults (``--jobs 2``: candidate fits
side by side): wall seconds from start to exit, and the CPU seconds of the call with its worker processes. The
flights are the slowest of the evaluation (``benchmarks.diagnose_evaluate``: forward2 flights with two or three
unmapped slabs, a 3,116-frame outdoor survey), long flights of the size the target names (``LONG_FLIGHTS``: 45-55 s
dwells, 4,000-5,100 frames, one to three slabs, and a null) and the shared datasets of up to 5,000 frames; forward2
flights are written as dataset folders first. Run it on an idle machine: the load average before each call is
printed with it.

    python benchmarks/diagnose_wall.py [--flights NAME ...] [--shared NAME ...] [--jsonl FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.shared_data import shared_path  # noqa: E402

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
SHARED = shared_path("datasets")
#: the evaluation's slowest calls (docs/diagnose-evaluation.md): two and three slabs, a long outdoor survey
FLIGHTS = ("uwall-1-spin-n2-s0", "uwall-0.5-spin-n3-s1", "uwall-1-lattice-n3-s2", "uwall-0.5-lattice-n1-s0",
           "conull-Cs-137-outdoor-19")
#: flights of the size the target names, 4,000-5,100 frames (the evaluation's are ~1,000): long dwells (45-55 s)
#: with one to three unmapped slabs, and a long null; (geometry, dwell s, slabs, mu x t, pose error, seed)
LONG_FLIGHTS = {
    "long-uwall-0.5-lattice-n2": ("lattice", 45.0, 2, 0.5, "independent", 81234),
    "long-uwall-0.5-spin-n1": ("spin", 50.0, 1, 0.5, "independent", 81235),
    "long-uwall-1-lattice-n3": ("lattice", 50.0, 3, 1.0, "random_walk", 81236),
    "long-null-lattice": ("lattice", 50.0, 0, 0.0, "independent", 81237),
    "long-uwall-0.5-spin-n2": ("spin", 55.0, 2, 0.5, "independent", 81238),
}
#: the shared datasets of at most 5,000 frames (outdoor-air has 6,463)
SHARED_NAMES = ("lattice-clean", "lattice-wall", "close-pass-deadtime", "spin-anisotropy", "two-sources")


def write_flights(names: list[str], out: Path) -> list[Path]:
    """The named forward2 flights as dataset folders under ``out``."""
    sys.path.insert(0, str(REPO))
    from benchmarks import diagnose_evaluate as ev
    from benchmarks.forward2 import FlightSpec, simulate
    from radseek_io.dataset import write_dataset

    every = {j["name"]: j for j in ev.jobs(["null", "pairs", "walls", "nuclides", "conull"], 4, 12, 60)
             + ev.offlist_jobs(2)}
    every.update({n: None for n in LONG_FLIGHTS})
    missing = [n for n in names if n not in every]
    if missing:
        raise SystemExit(f"no such flight: {', '.join(missing)} (names as in benchmarks.diagnose_evaluate)")
    paths = []
    for name in names:
        job = every[name] or long_flight_job(name)
        ds = simulate(FlightSpec(**job["spec"]), seed=job["seed"])
        paths.append(write_dataset(out / name, ds.frames, ds.scenario, ds.truth))
    return paths


def long_flight_job(name: str) -> dict:
    """The spec and seed of one of ``LONG_FLIGHTS`` (the forward2 random slabs, as the evaluation places them)."""
    import numpy as np

    from benchmarks.forward2 import FlightSpec, random_unmapped_wall

    geometry, dwell_s, slabs, mu_t, pose_error, seed = LONG_FLIGHTS[name]
    spec = {"geometry": geometry, "effects": {}, "crystal": "real", "pose_error": pose_error, "scatter": 0.02,
            "dwell_s": dwell_s}
    if slabs:
        spec["effects"] = {"unmapped_wall": random_unmapped_wall(FlightSpec(**spec), seed, mu_t,
                                                                 np.random.default_rng(seed), slabs)}
    return {"spec": spec, "seed": seed}


def diagnose_call(dataset: Path, out: Path) -> dict:
    """One ``radseek diagnose DATASET --json`` in its own process: wall and CPU seconds, what it named."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "radseek_cli", "diagnose", str(dataset), "--json", "--out", str(out)],
                          cwd=REPO, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    with (dataset / "frames.csv").open() as fh:
        frames = sum(1 for line in fh if line.strip() and not line.startswith("#")) - 1  # less the header
    row = {"flight": dataset.name, "frames": frames, "wall_s": round(wall, 1), "cpu_s": round(cpu, 1),
           "load_before": round(load, 2), "exit": proc.returncode}
    try:
        j = json.loads(proc.stdout)
        row.update(missing=j.get("missing"), unexplained=j.get("unexplained"))
    except json.JSONDecodeError:
        row["error"] = (proc.stderr.strip().splitlines() or ["no output"])[-1]
    return row


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--flights", nargs="*", default=list(FLIGHTS) + list(LONG_FLIGHTS),
                   help="forward2 flights (names as in benchmarks.diagnose_evaluate, or LONG_FLIGHTS' names)")
    p.add_argument("--shared", nargs="*", default=list(SHARED_NAMES), help="shared datasets")
    p.add_argument("--jsonl", type=Path, default=None, help="append one JSON row per call here")
    args = p.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="radseek-diagnose-wall-") as tmp:
        datasets = write_flights(args.flights, Path(tmp) / "flights") + [SHARED / n for n in args.shared]
        for k, ds in enumerate(datasets):
            row = diagnose_call(ds, Path(tmp) / f"out{k}")
            rows.append(row)
            print(json.dumps(row), flush=True)
            if args.jsonl:
                with args.jsonl.open("a") as fh:
                    fh.write(json.dumps(row) + "\n")
    print("\n| flight | frames | wall s | CPU s | load before | named |\n|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['flight']} | {r.get('frames', '-')} | {r['wall_s']} | {r['cpu_s']} | {r['load_before']} | "
              f"{', '.join(r.get('missing') or []) or ('unexplained' if r.get('unexplained') else '-')} |")
    return 0 if all(r["exit"] == 0 for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
