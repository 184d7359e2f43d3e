"""Sensor calibration (vehicle_sim/calibration.py) as PX4's commander runs it: which calibration a
MAV_CMD_PREFLIGHT_CALIBRATION asks for, its refusals, and the `[cal]` STATUSTEXTs in simulated time, checked against
the message formats MAVSDK's calibration plugin parses (calibration_statustext_parser.cpp) and PX4's orientation
routine (calibration_routines.cpp: more than 4 useless detections end in "timeout: no motion")."""

import math
import re

import pytest
from pymavlink.dialects.v20 import common as M

from vehicle_sim.calibration import MAX_ORIENTATION_FAILURES, Calibrations, requested

NAN = math.nan
GYRO = (1, 0, 0, 0, 0, NAN, NAN)  # as MAVSDK sends it: params 6-7 unset
ACCEL = (0, 0, 0, 0, 1, NAN, NAN)
LEVEL = (0, 0, 0, 0, 2, NAN, NAN)
MAG = (0, 1, 0, 0, 0, NAN, NAN)
CANCEL = (0, 0, 0, 0, 0, 0, 0)


@pytest.mark.parametrize("params, kind", [(GYRO, "gyro"), (ACCEL, "accel"), (LEVEL, "level"), (MAG, "mag"),
                                          ((0, 0, 1, 0, 0, 0, 0), "baro"), (CANCEL, "cancel"),
                                          ((0, 0, 0, 1, 0, 0, 0), "unsupported"),  # RC
                                          ((0, 0, 0, 0, 0, 2, 0), "unsupported"),  # airspeed
                                          ((0, 0, 0, 0, 0, 0, 1), "unsupported")])  # ESC
def test_the_calibration_asked_for_is_read_as_px4_commander_reads_it(params, kind):
    assert requested(params) == kind


def run(cal: Calibrations, until: float, dt: float = 0.05) -> list[tuple[float, str, int]]:
    out, t = [], 0.0
    while t <= until:
        out += [(t, text, sev) for text, sev in cal.due(t)]
        t += dt
    return out


def test_gyro_reports_progress_then_done_over_simulated_time():
    cal = Calibrations()
    assert cal.command(GYRO, armed=False, now=0.0) == M.MAV_RESULT_ACCEPTED
    assert cal.running == "gyro"
    texts = run(cal, 10.0)
    words = [t for _, t, _ in texts]
    assert words[0] == "[cal] calibration started: 2 gyro" and words[-1] == "[cal] calibration done: gyro"
    progress = [int(m.group(1)) for w in words if (m := re.fullmatch(r"\[cal\] progress <(\d+)>", w))]
    assert progress == sorted(progress) and progress[-1] == 100
    assert texts[-1][0] > 1.0  # it takes simulated time, not one burst
    assert cal.running is None  # done: another may start
    assert cal.command(LEVEL, armed=False, now=11.0) == M.MAV_RESULT_ACCEPTED


def test_accel_on_a_vehicle_nobody_turns_fails_as_px4_sitl_does():
    cal = Calibrations()
    assert cal.command(ACCEL, armed=False, now=0.0) == M.MAV_RESULT_ACCEPTED
    words = [t for _, t, _ in run(cal, 100.0)]
    assert words.count("[cal] down side done, rotate to a different side") == 2  # measured once (PX4 says it twice)
    assert words.count("[cal] down side already completed") == MAX_ORIENTATION_FAILURES + 1
    assert words[-2:] == ["[cal] calibration failed: timeout: no motion", "[cal] calibration failed: accel"]
    assert {"[cal] pending: back front left right up down", "[cal] pending: back front left right up"} <= set(words)
    assert all(w.startswith("[cal] ") and len(w) <= 50 for w in words)  # one STATUSTEXT each, MAVSDK's prefix
    assert cal.running is None


def test_refusals_and_cancel():
    cal = Calibrations()
    assert cal.command(GYRO, armed=True, now=0.0) == M.MAV_RESULT_TEMPORARILY_REJECTED
    assert cal.command((0, 0, 0, 1, 0, 0, 0), armed=False, now=0.0) == M.MAV_RESULT_UNSUPPORTED
    assert cal.running is None and run(cal, 5.0) == []  # refused: nothing said
    assert cal.command(CANCEL, armed=False, now=0.0) == M.MAV_RESULT_ACCEPTED  # nothing to cancel: accepted, quiet
    assert run(cal, 1.0) == []
    assert cal.command(MAG, armed=False, now=0.0) == M.MAV_RESULT_ACCEPTED
    assert cal.command(GYRO, armed=False, now=0.5) == M.MAV_RESULT_TEMPORARILY_REJECTED  # busy
    first = run(cal, 0.5)
    assert cal.command(CANCEL, armed=False, now=1.0) == M.MAV_RESULT_ACCEPTED
    rest = [t for _, t, _ in run(cal, 100.0)]
    assert first and rest == ["[cal] calibration cancelled"]
    assert cal.running is None
