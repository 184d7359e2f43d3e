"""Export a planned mission as a QGroundControl ``.plan`` file (JSON, mission version 2).

Items are written as QGC "SimpleItem"s with their raw command, frame and the seven params
(lat/lon in degrees); NaN params become ``null`` as QGC writes them. A geofence (inclusion/exclusion
polygons and circles, lat/lon degrees) and rally points go in the file's ``geoFence`` and
``rallyPoints`` sections. QGroundControl opens the file, and MAVSDK's
``mission_raw.import_qgroundcontrol_mission`` reads it back. ``read_plan`` reads one (ours or QGC's
SimpleItems) into raw mission, fence and rally items ready for the mission protocol.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from radseek.coordinates import Home

MAV_AUTOPILOT_PX4 = 12
MAV_TYPE_QUADROTOR = 2
GLOBAL_FRAMES = {0, 3, 5, 6}
ALTITUDE_MODE = {0: 2, 5: 2, 3: 1, 6: 1}  # QGC AltitudeMode: 1 relative to launch, 2 AMSL


def _num(v: float) -> float | None:
    return None if v is None or (isinstance(v, float) and not math.isfinite(v)) else v


def plan_dict(items: list[Any], home: Home, *, cruise_speed: float = 3.0, hover_speed: float = 3.0,
              polygons: list[tuple[bool, list[tuple[float, float]]]] = (),
              circles: list[tuple[bool, tuple[float, float], float]] = (),
              rally: list[tuple[float, float, float]] = ()) -> dict:
    """``items`` are raw mission items (MAVSDK mission_raw ``MissionItem`` or anything with its fields);
    ``polygons`` (inclusion?, [(lat, lon), ...]), ``circles`` (inclusion?, (lat, lon), radius m) and
    ``rally`` points (lat, lon, alt m relative to home) fill the geofence and rally sections."""
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
        "geoFence": {"version": 2,
                     "circles": [{"inclusion": bool(inc), "version": 1,
                                  "circle": {"center": [float(c[0]), float(c[1])], "radius": float(r)}}
                                 for inc, c, r in circles],
                     "polygons": [{"inclusion": bool(inc), "version": 1,
                                   "polygon": [[float(a), float(b)] for a, b in pts]} for inc, pts in polygons]},
        "rallyPoints": {"version": 2, "points": [[float(a), float(b), float(c)] for a, b, c in rally]},
    }


def write_plan(path: str | Path, items: list[Any], home: Home, **kwargs: Any) -> Path:
    path = Path(path)
    path.write_text(json.dumps(plan_dict(items, home, **kwargs), indent=2, allow_nan=False))
    return path


@dataclass
class RawItem:
    """One mission-protocol item (the fields of MISSION_ITEM_INT; x, y degE7 in global frames)."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float
    mission_type: int


class PlanError(ValueError):
    pass


def _f(v: Any) -> float:
    return math.nan if v is None else float(v)


def read_plan(path: str | Path) -> tuple[list[RawItem], list[RawItem], list[RawItem]]:
    """(mission, fence, rally) items of a QGC .plan file. SimpleItems are read as they are; a transect-style
    ComplexItem (QGC's ``survey`` and ``CorridorScan``) as the SimpleItems QGC saved inside it
    (``TransectStyleComplexItem.Items``, the waypoints and camera commands it flies). Other ComplexItems (a
    structure scan) are a PlanError naming the item."""
    try:
        doc = json.loads(Path(path).read_text())
        raw_items = doc["mission"]["items"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise PlanError(f"{path}: not a QGC .plan file ({exc})") from None
    flat: list[tuple[str, Any]] = []
    for k, it in enumerate(raw_items):
        if not isinstance(it, dict):
            raise PlanError(f"{path}: item {k} is not an object")
        if it.get("type") == "ComplexItem":
            inner = (it.get("TransectStyleComplexItem") or {}).get("Items")
            if not isinstance(inner, list) or not inner:
                raise PlanError(f"{path}: item {k} is a {it.get('complexItemType')!r} ComplexItem without saved "
                                "items (TransectStyleComplexItem.Items); only surveys and corridor scans are read")
            flat += [(f"item {k} ({it.get('complexItemType')}) sub-item {j}", sub) for j, sub in enumerate(inner)]
        else:
            flat.append((f"item {k}", it))
    mission: list[RawItem] = []
    for where, it in flat:
        if not isinstance(it, dict) or it.get("type") != "SimpleItem":
            raise PlanError(f"{path}: {where} is a {it.get('type') if isinstance(it, dict) else it!r}, "
                            "not a SimpleItem")
        try:
            p = [_f(v) for v in it["params"]]
            if len(p) != 7:
                raise ValueError(f"{len(p)} params, 7 expected")
            frame, command = int(it["frame"]), int(it["command"])
            glob = frame in GLOBAL_FRAMES
            x = int(round(p[4] * 1e7)) if glob else int(0 if math.isnan(p[4]) else p[4])
            y = int(round(p[5] * 1e7)) if glob else int(0 if math.isnan(p[5]) else p[5])
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise PlanError(f"{path}: {where}: bad SimpleItem ({type(exc).__name__}: {exc})") from None
        mission.append(RawItem(len(mission), frame, command, 1 if not mission else 0,
                               int(bool(it.get("autoContinue", True))), p[0], p[1], p[2], p[3], x, y,
                               0.0 if math.isnan(p[6]) else p[6], 0))
    fence: list[RawItem] = []
    gf = doc.get("geoFence") or {}
    for poly in gf.get("polygons", []):
        pts = poly["polygon"]
        cmd = 5001 if poly.get("inclusion", True) else 5002  # NAV_FENCE_POLYGON_VERTEX_INCLUSION/EXCLUSION
        for lat, lon in pts:
            fence.append(RawItem(len(fence), 5, cmd, 0, 1, float(len(pts)), 0, 0, 0, int(round(lat * 1e7)),
                                 int(round(lon * 1e7)), 0.0, 1))
    for c in gf.get("circles", []):
        cmd = 5003 if c.get("inclusion", True) else 5004  # NAV_FENCE_CIRCLE_INCLUSION/EXCLUSION
        lat, lon = c["circle"]["center"]
        fence.append(RawItem(len(fence), 5, cmd, 0, 1, float(c["circle"]["radius"]), 0, 0, 0,
                             int(round(lat * 1e7)), int(round(lon * 1e7)), 0.0, 1))
    rally = [RawItem(k, 3, 5100, 0, 1, 0, 0, 0, 0, int(round(lat * 1e7)), int(round(lon * 1e7)), float(alt), 2)
             for k, (lat, lon, alt) in enumerate((doc.get("rallyPoints") or {}).get("points", []))]
    return mission, fence, rally
