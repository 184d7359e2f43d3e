"""The mission layer's MAVLink client, built on MAVSDK (mission_raw, action, telemetry) so the same code
flies the mock vehicle, PX4 or ArduPilot. One small module per capability, each with its own result
type and exception, like MAVSDK itself:

- ``connection``: connect, wait for a healthy vehicle (``Connection``, ``ConnectionFailed``)
- ``action``: arm, takeoff, land, RTL, hold, go-to (``Actions``, ``ActionFailed``)
- ``mission_upload``: dwell points -> raw mission, upload/replace, start, end a dwell, progress
  (``MissionControl``, ``MissionFailed``)
- ``telemetry``: position in local ENU, armed / in-air, battery, status texts (``TelemetryWatch``)
"""
