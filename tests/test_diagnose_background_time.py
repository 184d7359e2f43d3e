"""The verdict's changing-background check (``estimator.diagnose.background_time``) on flights of the independent
forward model (``benchmarks.forward2``, measured RadiaCode-102 spectra): a background that rises and falls during
the flight beats the second source that stands in for it; a true second source or background gradient is not taken
for a changing background."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks.forward2 import FlightSpec, simulate
from estimator.diagnose.background_time import MIN_PERIOD_S, background_time_check, period_starts
from estimator.diagnose.verdict import STRONG_AIC
from tests.support.off_list import run_check


def _check(spec: FlightSpec, seed: int, stand_in: tuple[str, ...]):
    return run_check(background_time_check, spec, seed, stand_in)


def test_the_period_starts_are_the_frequencies_a_flight_can_tell_apart():
    """Frequencies 1/T apart from 1/(2T) up to the last one under 1/MIN_PERIOD_S (T the flight's span)."""
    ds = simulate(FlightSpec(geometry="lawnmower"), seed=3)
    p = period_starts(ds.frames)
    span = ds.frames.t[-1] - ds.frames.t[0]
    f = 1 / p
    assert f[0] == pytest.approx(0.5 / span) and np.allclose(np.diff(f), 1 / span)
    assert p[-1] >= MIN_PERIOD_S and 1 / (f[-1] + 1 / span) < MIN_PERIOD_S


@pytest.mark.slow
def test_a_background_rising_and_falling_beats_the_second_source_standing_in_for_it():
    """A 100 cps background swinging by 70 % with a 45 s period on a lawnmower: the second source fitted to it
    loses to a changing background by far more than the threshold, at a period near the true one."""
    spec = FlightSpec(geometry="lawnmower", background_cps=100.0, scatter=0.02,
                      effects={"background_drift": {"amplitude": 0.7, "period_s": 45.0, "phase": 0.3}})
    ds, bt = _check(spec, seed=1, stand_in=("second_source",))
    assert bt.threshold == pytest.approx(STRONG_AIC + 2 * math.log(bt.looks))
    assert bt.significant and bt.aic_gap > 3 * bt.threshold
    assert bt.period_s == pytest.approx(45.0, rel=0.1)
    assert abs(bt.amplitude) == pytest.approx(0.7, abs=0.15)


@pytest.mark.slow
@pytest.mark.parametrize(("geometry", "effects", "stand_in"), [
    ("lawnmower", {"second_source": {"x": 8.5, "y": 1.5, "z": 0.0, "cps_at_1m": 1300.0}}, ("second_source",)),
    ("lawnmower", {"background_gradient": {"gx": 0.0, "gy": 4.0}}, ("background_gradient",)),
])
def test_a_true_effect_is_not_taken_for_a_changing_background(geometry, effects, stand_in):
    """A lawnmower sweeps the area in time order, so a second source or a gradient rises with time as well: the
    true effect still fits better than any background changing in time."""
    _, bt = _check(FlightSpec(geometry=geometry, effects=effects, scatter=0.02), seed=2, stand_in=stand_in)
    assert not bt.significant
