"""Sensor calibration as PX4's commander runs it (MAV_CMD_PREFLIGHT_CALIBRATION), told as PX4 tells it: the
command is ACCEPTED, then the progress comes as PX4's ``[cal]`` STATUSTEXTs (its calibration_messages.h), which
QGroundControl and MAVSDK's calibration plugin parse. Paced in simulated time.

What a SITL vehicle can do: gyro, level horizon and baro calibrate at rest and succeed (started, progress,
done). Accelerometer and magnetometer need the vehicle held on each of its six sides in turn, which nobody can do
to a simulated airframe standing on the ground: as PX4's ``calibrate_from_orientation`` (calibration_routines.cpp)
does then, the down side is measured, the down side is found again five times ("already completed"), and the
calibration fails with ``timeout: no motion`` (the magnetometer's turn about each side is not simulated:
its down side is taken as measured too). Armed or already calibrating: TEMPORARILY_REJECTED; all parameters
0 cancels a running calibration (``[cal] calibration cancelled``); RC, airspeed, ESC and temperature calibration
(hardware the simulation has not): UNSUPPORTED."""

from __future__ import annotations

import math
from collections import deque

from pymavlink.dialects.v20 import common as M

SIDES = ("back", "front", "left", "right", "up", "down")  # PX4's detect_orientation_str order
STEP_S = 0.2  # sim s between two messages of a step-by-step routine
MEASURE_S = 2.0  # sim s a calibration at rest takes (PX4 averages ~2 s of samples)
STILL_S = 2.0  # sim s PX4's orientation detection waits for the vehicle to be still
MAX_ORIENTATION_FAILURES = 4  # PX4: more than this many useless detections -> "timeout: no motion"
INFO, CRITICAL = M.MAV_SEVERITY_INFO, M.MAV_SEVERITY_CRITICAL


def _at_rest(name: str) -> list[tuple[float, str, int]]:
    """Gyro, level or baro: started, progress every 10 %, done (delays in sim s from the previous message)."""
    texts = [(0.0, f"[cal] calibration started: 2 {name}", INFO)]
    texts += [(MEASURE_S / 10, f"[cal] progress <{p}>", INFO) for p in range(10, 101, 10)]
    return texts + [(STEP_S, f"[cal] calibration done: {name}", INFO)]


def _by_orientation(name: str) -> list[tuple[float, str, int]]:
    """Accelerometer or magnetometer on a vehicle nobody turns: the down side only, then PX4's timeout."""
    texts = [(0.0, f"[cal] calibration started: 2 {name}", INFO)]
    done: set[str] = set()
    failures = 0
    while failures <= MAX_ORIENTATION_FAILURES:
        texts.append((STEP_S, "[cal] pending: " + " ".join(s for s in SIDES if s not in done), INFO))
        texts.append((STEP_S, "[cal] hold vehicle still on a pending side", INFO))
        texts.append((STILL_S, "[cal] detected rest position, hold still...", INFO))
        if "down" in done:
            failures += 1
            texts.append((STEP_S, "[cal] down side already completed", INFO))
            continue
        texts += [(STEP_S, "[cal] down orientation detected", INFO)] * 2
        if name == "accel":  # PX4's accel worker: the specific force at rest, body FRD
            texts.append((STEP_S, "[cal] Hold still, measuring down side", INFO))
            texts.append((MEASURE_S, "[cal] down side result: [0.000 0.000 -9.807]", INFO))
        else:  # its mag worker wants a turn about the side's axis; the vehicle stands still (approximated)
            texts.append((MEASURE_S, "[cal] Rotate vehicle around the detected orientation", INFO))
        texts.append((STEP_S, "[cal] progress <17>", INFO))  # PX4: 17 % per side done
        texts += [(STEP_S, "[cal] down side done, rotate to a different side", INFO)] * 2
        done.add("down")
    return texts + [(STEP_S, "[cal] calibration failed: timeout: no motion", CRITICAL),
                    (STEP_S, f"[cal] calibration failed: {name}", CRITICAL)]


ROUTINES = {"gyro": lambda: _at_rest("gyro"), "level": lambda: _at_rest("level"), "baro": lambda: _at_rest("baro"),
            "accel": lambda: _by_orientation("accel"), "mag": lambda: _by_orientation("mag")}


def requested(params: tuple[float, ...]) -> str | None:
    """The calibration MAV_CMD_PREFLIGHT_CALIBRATION's params 1-7 ask for, as PX4's commander reads them: 'gyro',
    'mag', 'baro', 'accel', 'level', 'cancel' (all 0), 'unsupported' (RC, airspeed, ESC, temperature...)."""
    p = [int(v) if math.isfinite(v) else 0 for v in params]  # NaN: unset (MAVSDK sends it for params 6-7)
    if p[0] == 1:
        return "gyro"
    if p[1] == 1:
        return "mag"
    if p[2] == 1:
        return "baro"
    if p[4] == 1:
        return "accel"
    if p[4] == 2:
        return "level"
    if not any(p[:6]) and p[6] != 1:  # param7 1 is ESC calibration
        return "cancel"
    return "unsupported"


class Calibrations:
    """The calibration running (if any) and its messages still to send, in simulated time."""

    def __init__(self):
        self.running: str | None = None
        self._texts: deque[tuple[float, str, int]] = deque()  # (sim s due, text, severity)

    def command(self, params: tuple[float, ...], armed: bool, now: float) -> int:
        """Handle one MAV_CMD_PREFLIGHT_CALIBRATION (params 1-7); returns its MAV_RESULT."""
        kind = requested(params)
        if kind == "cancel":
            if self.running is not None:
                self.running = None
                self._texts = deque([(now, "[cal] calibration cancelled", CRITICAL)])
            return M.MAV_RESULT_ACCEPTED
        if armed or self.running is not None:
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if kind == "unsupported":
            return M.MAV_RESULT_UNSUPPORTED
        self.running = kind
        t = now
        for delay, text, severity in ROUTINES[kind]():
            t += delay
            self._texts.append((t, text, severity))
        return M.MAV_RESULT_ACCEPTED

    def due(self, now: float) -> list[tuple[str, int]]:
        """The messages due by sim time ``now`` (text, severity); the calibration ends with its last one."""
        out = []
        while self._texts and self._texts[0][0] <= now + 1e-9:
            _, text, severity = self._texts.popleft()
            out.append((text, severity))
        if not self._texts:
            self.running = None
        return out
