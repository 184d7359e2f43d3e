"""An off-list check (``estimator.diagnose.motion``, ``estimator.diagnose.background_time``) run as diagnose runs
it: on a flight of the independent forward model, the named model (the effects that stand in for the off-list
physics) fitted first, then the check against it from the start model."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from benchmarks.forward2 import FlightSpec, simulate
from estimator.diagnose.backend import split_transit_legs
from estimator.mle import fit
from estimator.model import MeasurementModel


def run_check(check: Callable[..., Any], spec: FlightSpec, seed: int, stand_in: tuple[str, ...]):
    """The simulated dataset and ``check(start, frames, named)`` on it."""
    ds = simulate(spec, seed=seed)
    frames = split_transit_legs(ds.frames)
    named = fit(MeasurementModel(ds.scenario, stand_in), frames, n_starts=4)
    return ds, check(MeasurementModel(ds.scenario, ()), frames, named)
