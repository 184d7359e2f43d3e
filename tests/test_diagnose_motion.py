"""The verdict's moved-source check (``estimator.diagnose.motion``) on flights of the independent forward model
(``benchmarks.forward2``, measured RadiaCode-102 spectra): a source carried off mid-flight beats the effects that
stand in for it; true effects of the vocabulary are not taken for a moved source."""

from __future__ import annotations

import math

import pytest

from benchmarks.forward2 import FlightSpec, simulate
from estimator.diagnose.motion import BREAKS, break_times, motion_check
from estimator.diagnose.verdict import STRONG_AIC
from tests.support.off_list import run_check

STAND_INS = ("second_source", "pose_drift")


def _check(spec: FlightSpec, seed: int):
    return run_check(motion_check, spec, seed, STAND_INS)


def test_the_looks_span_the_flight_and_the_threshold_pays_for_them():
    ds = simulate(FlightSpec(geometry="lawnmower"), seed=3)
    t = break_times(ds.frames)
    span = ds.frames.t[-1] - ds.frames.t[0]
    assert len(t) == len(BREAKS) and t[0] == pytest.approx(ds.frames.t[0] + 0.2 * span)
    assert t[-1] == pytest.approx(ds.frames.t[0] + 0.8 * span)


@pytest.mark.slow
def test_a_source_carried_off_mid_flight_beats_a_drift_and_a_second_source():
    """Still until 45 % of the flight, then carried at (0.1, -0.1) m/s: one moved source fits better than pose
    drift plus a second source (AIC gap far above the threshold), found from a break near the true one with the
    carried velocity."""
    spec = FlightSpec(geometry="spin", effects={"moving_source": {"vx": 0.1, "vy": -0.1, "start_fraction": 0.45}},
                      scatter=0.02)
    ds, mc = _check(spec, seed=1)
    assert mc.significant and mc.aic_gap > 5 * mc.threshold
    assert mc.threshold == pytest.approx(STRONG_AIC + 2 * math.log(len(BREAKS)))
    true_t0 = 0.45 * ds.frames.t[-1]
    assert abs(mc.t0_s - true_t0) <= 0.1 * ds.frames.t[-1]  # the nearest look (breaks a tenth of the flight apart)
    # the break is a look, not the true time: the velocity is the carried one within 25 % (a break 1-5 s off)
    assert math.hypot(mc.velocity[0] - 0.1, mc.velocity[1] + 0.1) <= 0.25 * math.hypot(0.1, 0.1)


@pytest.mark.slow
def test_a_true_drift_and_second_source_are_not_taken_for_a_moved_source():
    spec = FlightSpec(geometry="spin", effects={"pose_drift": {"vx": 0.01, "vy": -0.01},
                                                "second_source": {"x": 8.5, "y": 1.5, "z": 0.0, "cps_at_1m": 1300.0}},
                      scatter=0.02)
    _, mc = _check(spec, seed=1)
    assert not mc.significant
