"""What a diagnose call costs and whether a speed change moved its answer (issue 30 item 6): named flights of
``benchmarks.diagnose_evaluate`` run in this process with ``run_one``'s settings (``--starts 4``, one process).

    python -m benchmarks.diagnose_cost --jobs NAME [NAME ...] [--jsonl FILE]

Per call: CPU seconds, likelihood calls (every MIGRAD and HESSE call, the screens' calls without pose offsets
included), the effects named, deviance/dof, the final model's -log L and every selection candidate's -log L and
log10 p, so two versions of the code can be compared fit by fit. CPU seconds are the figure on a shared machine
(wall time is not measured).
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

from benchmarks import diagnose_evaluate as evaluate
from estimator import mle

CALLS = [0]


def _count() -> None:
    """Count the likelihood's calls (every fit goes through ``mle._Likelihood``)."""
    call = mle._Likelihood.__call__

    def counted(self: mle._Likelihood, *values: float) -> float:
        CALLS[0] += 1
        return call(self, *values)

    mle._Likelihood.__call__ = counted


def named_jobs(names: list[str]) -> list[dict[str, Any]]:
    every = evaluate.jobs(["null", "pairs", "walls"], 3, 12) + evaluate.offlist_jobs(2)
    by_name = {j["name"]: j for j in every}
    missing = [n for n in names if n not in by_name]
    if missing:
        raise SystemExit(f"no such job: {', '.join(missing)} (names as in benchmarks.diagnose_evaluate)")
    return [by_name[n] for n in names]


def run(job: dict[str, Any]) -> dict[str, Any]:
    from benchmarks.forward2 import FlightSpec, simulate
    from estimator.diagnose.runner import diagnose

    ds = simulate(FlightSpec(**job["spec"]), seed=job["seed"])
    CALLS[0] = 0
    c0 = time.process_time()
    d = diagnose(ds, quiet=True, n_starts=4)
    cpu = time.process_time() - c0
    return {"name": job["name"], "frames": len(ds.frames), "cpu_seconds": round(cpu, 1), "likelihood_calls": CALLS[0],
            "selected": d.selection.missing, "named": d.missing, "partial": d.partial, "unexplained": d.unexplained,
            "deviance_per_dof": round(d.final.gof.deviance_per_dof, 4), "final_nll": round(d.final.fit.nll, 3),
            "steps": [[(c.effect, round(getattr(c.fit, "nll", float("nan")), 2), round(c.log10_p, 2))
                       for c in st.candidates] for st in d.selection.steps]}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--jobs", nargs="+", required=True)
    ap.add_argument("--jsonl", default=None)
    args = ap.parse_args(argv)
    _count()
    for job in named_jobs(args.jobs):
        row = json.dumps(run(job))
        print(row, flush=True)
        if args.jsonl:
            with open(args.jsonl, "a") as f:
                f.write(row + "\n")


if __name__ == "__main__":
    main()
