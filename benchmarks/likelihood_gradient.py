"""What the likelihood's gradient for MIGRAD saves (issue 30 item 6): diagnose calls and single fits with MIGRAD's
own finite differences (``estimator.mle.USE_GRADIENT = False``) and with the gradient, on named flights of
``benchmarks.diagnose_evaluate``.

    python -m benchmarks.likelihood_gradient --jobs NAME [NAME ...] [--mode before after] [--jsonl FILE]

Per call: CPU seconds, likelihood calls and gradient calls (all MIGRAD and HESSE calls, the screen's likelihood
without pose offsets included), the effects named, deviance/dof before and after, the source error. CPU seconds
are the figure on a shared machine (wall time is not measured).
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from benchmarks import diagnose_evaluate as evaluate
from estimator import mle

CALLS = {"fcn": 0, "grad": 0}


def _count() -> None:
    """Count the likelihood's and its gradient's calls (every fit goes through ``mle._Likelihood``)."""
    call, grad = mle._Likelihood.__call__, mle._Likelihood.grad

    def counted_call(self: mle._Likelihood, *values: float) -> float:
        CALLS["fcn"] += 1
        return call(self, *values)

    def counted_grad(self: mle._Likelihood, *values: float) -> Any:
        CALLS["grad"] += 1
        return grad(self, *values)

    mle._Likelihood.__call__, mle._Likelihood.grad = counted_call, counted_grad


def named_jobs(names: list[str]) -> list[dict[str, Any]]:
    every = evaluate.jobs(["null", "pairs", "walls"], 3, 12) + evaluate.offlist_jobs(2)
    by_name = {j["name"]: j for j in every}
    missing = [n for n in names if n not in by_name]
    if missing:
        raise SystemExit(f"no such job: {', '.join(missing)} (names as in benchmarks.diagnose_evaluate)")
    return [by_name[n] for n in names]


def run(job: dict[str, Any], mode: str) -> dict[str, Any]:
    mle.USE_GRADIENT = mode == "after"
    CALLS.update(fcn=0, grad=0)
    r = evaluate.run_one(job)
    keep = ("name", "frames", "named", "unexplained", "dev_before", "dev_after", "err_before", "err_after",
            "cpu_seconds", "unmapped_walls")
    return {"mode": mode, **{k: r.get(k) for k in keep}, "likelihood_calls": CALLS["fcn"],
            "gradient_calls": CALLS["grad"]}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--jobs", nargs="+", required=True)
    ap.add_argument("--mode", nargs="+", default=["before", "after"], choices=["before", "after"])
    ap.add_argument("--jsonl", default=None)
    args = ap.parse_args(argv)
    _count()
    for job in named_jobs(args.jobs):
        for mode in args.mode:
            row = run(job, mode)
            print(json.dumps(row), flush=True)
            if args.jsonl:
                with open(args.jsonl, "a") as f:
                    f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
