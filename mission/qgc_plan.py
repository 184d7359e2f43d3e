"""Export a planned mission as a QGroundControl ``.plan`` file (JSON, mission version 2).

Items are written as QGC "SimpleItem"s with their raw command, frame and the seven params
(lat/lon in degrees); NaN params become ``null`` as QGC writes them. QGroundControl opens the file,
and MAVSDK's ``mission_raw.import_qgroundcontrol_mission`` reads it back.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from radseek.coordinates import Home

MAV_AUTOPILOT_PX4 = 12
MAV_TYPE_QUADROTOR = 2
GLOBAL_FRAMES = {0, 3, 5, 6}
ALTITUDE_MODE = {0: 2, 5: 2, 3: 1, 6: 1}  # QGC AltitudeMode: 1 relative to launch, 2 AMSL


def _num(v: float) -> float | None:
    return None if v is None or (isinstance(v, float) and not math.isfinite(v)) else v


def plan_dict(items: list[Any], home: Home, *, cruise_speed: float = 3.0, hover_speed: float = 3.0) -> dict:
    """``items`` are raw mission items (MAVSDK mission_raw ``MissionItem`` or anything with its fields)."""
    out = []
    for k, it in enumerate(items):
        glob = it.frame in GLOBAL_FRAMES
        # QGC stores global positions in plain frame 3/0 with degrees
        frame = {5: 0, 6: 3}.get(it.frame, it.frame)
        lat = it.x / 1e7 if glob else float(it.x)
        lon = it.y / 1e7 if glob else float(it.y)
        entry: dict[str, Any] = {
            "type": "SimpleItem", "autoContinue": bool(it.autocontinue), "command": int(it.command),
            "doJumpId": k + 1, "frame": int(frame),
            "params": [_num(float(it.param1)), _num(float(it.param2)), _num(float(it.param3)),
                       _num(float(it.param4)), lat, lon, _num(float(it.z))],
        }
        if glob:
            entry.update({"Altitude": float(it.z), "AltitudeMode": ALTITUDE_MODE[it.frame],
                          "AMSLAltAboveTerrain": None})
        out.append(entry)
    return {
        "fileType": "Plan", "version": 1, "groundStation": "radseek",
        "mission": {"version": 2, "firmwareType": MAV_AUTOPILOT_PX4, "vehicleType": MAV_TYPE_QUADROTOR,
                    "cruiseSpeed": cruise_speed, "hoverSpeed": hover_speed, "items": out,
                    "plannedHomePosition": [home.lat_deg, home.lon_deg, home.alt_m]},
        "geoFence": {"version": 2, "circles": [], "polygons": []},
        "rallyPoints": {"version": 2, "points": []},
    }


def write_plan(path: str | Path, items: list[Any], home: Home, **kwargs: Any) -> Path:
    path = Path(path)
    path.write_text(json.dumps(plan_dict(items, home, **kwargs), indent=2, allow_nan=False))
    return path
