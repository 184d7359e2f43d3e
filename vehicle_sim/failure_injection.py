"""Failure injection as PX4 SITL offers it (MAV_CMD_INJECT_FAILURE, enabled by the SYS_FAILURE_EN parameter): what
hardware-in-the-loop-style fault tests use. Supported: the GPS receiver and the battery monitor, types OK (clear)
and OFF (the sensor stops reporting). Effects on telemetry: GPS off -> GPS_RAW_INT says no GPS (fix type NO_GPS)
and SYS_STATUS clears the GPS present/enabled/healthy bits; battery off -> BATTERY_STATUS and SYS_STATUS carry no
voltage or charge (MAVLink's "unknown" values) and the battery health bit is cleared. The flight itself goes on:
the vehicle navigates on its own odometry (GPS-denied) and the battery is still there, only unmonitored.

As PX4: with SYS_FAILURE_EN 0 every injection is DENIED; a unit or type it does not simulate is UNSUPPORTED; the
instance (param3) is accepted as 0 (all) or 1 (the one sensor)."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as M

UNITS = {M.FAILURE_UNIT_SENSOR_GPS: "gps", M.FAILURE_UNIT_SYSTEM_BATTERY: "battery"}
TYPES = (M.FAILURE_TYPE_OK, M.FAILURE_TYPE_OFF)


class Failures:
    """The failures injected so far: ``active`` holds the names of the units turned off."""

    def __init__(self):
        self.enabled = False  # SYS_FAILURE_EN
        self.active: set[str] = set()

    def inject(self, unit: int, ftype: int, instance: int) -> tuple[int, str]:
        """Apply one MAV_CMD_INJECT_FAILURE; returns (MAV_RESULT, what happened for a STATUSTEXT)."""
        if not self.enabled:
            return M.MAV_RESULT_DENIED, "failure injection disabled (SYS_FAILURE_EN 0)"
        name = UNITS.get(unit)
        if name is None or ftype not in TYPES or instance not in (0, 1):
            return M.MAV_RESULT_UNSUPPORTED, f"failure unit {unit} type {ftype} instance {instance} not simulated"
        if ftype == M.FAILURE_TYPE_OFF:
            self.active.add(name)
            return M.MAV_RESULT_ACCEPTED, f"Failure injected: {name} off"
        self.active.discard(name)
        return M.MAV_RESULT_ACCEPTED, f"Failure cleared: {name} ok"
