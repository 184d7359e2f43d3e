"""CPU seconds of one second-source nuclide identification (``estimator.diagnose.nuclide``), the figure the
nuclide tests used to assert (< 10 s a call): their flights (a Cs-137 primary, each candidate as the second
source, strong and moderate, from the measured RC-102 spectra), timed here instead of in a test.

    python benchmarks/nuclide_identify.py [--quick]

Prints, per flight, the nuclide named, the log-likelihood gap, and the CPU seconds of the call (the crystal's
calibration among them); then the median and the maximum.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from tests.test_diagnose_nuclide import flight, identify  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="two seeds per nuclide instead of five")
    args = ap.parse_args(argv)
    seeds = ((0, 1300.0), (2, 100.0)) if args.quick else ((0, 1300.0), (1, 1300.0), (2, 100.0), (3, 100.0),
                                                          (4, 100.0))
    identify(*flight("Cs-137", "Co-60", 1300.0, 0), "Cs-137")  # libraries' tables and caches loaded
    cpu = []
    for second in ("Co-60", "Ba-133", "Eu-152", "Cs-137", "Am-241"):
        for seed, cps in seeds:
            f, e = flight("Cs-137", second, cps, seed)
            t0 = time.process_time()
            choice = identify(f, e, "Cs-137")
            cpu.append(time.process_time() - t0)
            print(f"{second:7s} seed {seed} {cps:6.0f} cps: named {choice.nuclide}, gap {choice.gap:6.1f}, "
                  f"{cpu[-1]:.2f} s CPU", flush=True)
    print(f"CPU per identification: median {np.median(cpu):.2f} s, max {max(cpu):.2f} s ({len(cpu)} calls)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
