"""The flight in Foxglove's well-known schemas, derived from the radseek and MAVLink messages the MCAP log
records, so that Foxglove's (or Lichtblick's) Map and 3D panels show it with no script.

Frames: ``map`` is the stack's local ENU frame (metres about the home point); each vehicle's body frame is
named after the vehicle (``uav0``), its simulated truth ``<vehicle>/truth``. Channels (JSON, schemas from
:mod:`radseek_io.foxglove_schemas`):

- ``foxglove/<vehicle>/location`` (``foxglove.LocationFix``): the vehicle's global position, from MAVLink
  ``GLOBAL_POSITION_INT`` when the vehicle's MAVLink is recorded, else from its estimated ``pose`` through
  the home point (``radseek.coordinates``), with the pose's variances as a diagonal ENU covariance;
- ``foxglove/<vehicle>/pose`` and ``foxglove/<vehicle>/truth_pose`` (``foxglove.PoseInFrame``, frame
  ``map``): the estimated pose, and in simulation the true one (``sim/truth_pose``);
- ``foxglove/<vehicle>/tf`` (``foxglove.FrameTransform``): ``map`` -> ``<vehicle>`` (estimate) and
  ``map`` -> ``<vehicle>/truth``;
- ``foxglove/map`` (``foxglove.SceneUpdate``): the scenario's flight-area bounds and walls;
- ``foxglove/<vehicle>/scene`` (``foxglove.SceneUpdate``): the planned path and dwell points (``plan``), each
  estimated source with its x-y covariance ellipses, 1-sigma and 95 % (``estimate``).

Scene updates are sent again every ``SCENE_PERIOD_S`` of simulation time, so that a player that seeks into
the middle of the file finds the walls and the plan within a second.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from radseek import topics
from radseek.coordinates import Home, enu_to_geodetic, yaw_enu_to_ned
from radseek.dataset import Scenario

MAP_FRAME = "map"
SCENE_PERIOD_S = 1.0
ELLIPSE_POINTS = 48
CHI2_95_2D = 5.991  # chi-square quantile, 2 degrees of freedom, 95 %
#: MAVLink GLOBAL_POSITION_INT.hdg when the heading is unknown
HDG_UNKNOWN = 65535
COVARIANCE_UNKNOWN, COVARIANCE_DIAGONAL_KNOWN = 0, 2
LINE_STRIP, LINE_LOOP = 0, 1

Message = tuple[str, str, dict[str, Any]]  # (channel, schema name foxglove.X, JSON message)


def stamp(ns: int) -> dict[str, int]:
    """A Foxglove time from nanoseconds."""
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _vec(x: float, y: float, z: float) -> dict[str, float]:
    return {"x": float(x), "y": float(y), "z": float(z)}


def _quat_yaw(yaw: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)}


def _pose(x: float, y: float, z: float, yaw: float = 0.0) -> dict[str, Any]:
    return {"position": _vec(x, y, z), "orientation": _quat_yaw(yaw)}


def _color(r: float, g: float, b: float, a: float = 1.0) -> dict[str, float]:
    return {"r": r, "g": g, "b": b, "a": a}


def _line(points, color, kind: int = LINE_STRIP, thickness: float = 0.05) -> dict[str, Any]:
    return {"type": kind, "pose": _pose(0, 0, 0), "thickness": thickness, "scale_invariant": False,
            "points": [_vec(*p) for p in points], "color": color, "colors": [], "indices": []}


def _sphere(p, size: float, color) -> dict[str, Any]:
    return {"pose": _pose(*p), "size": _vec(size, size, size), "color": color}


def _entity(ns: int, eid: str, **primitives: list) -> dict[str, Any]:
    e = {"timestamp": stamp(ns), "frame_id": MAP_FRAME, "id": eid, "lifetime": {"sec": 0, "nsec": 0},
         "frame_locked": False, "metadata": []}
    for kind in ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models"):
        e[kind] = primitives.get(kind, [])
    return e


def _ellipse(cx: float, cy: float, z: float, cov_xy: np.ndarray, scale: float) -> list[tuple[float, float, float]]:
    """Points of the ellipse ``x^T C^-1 x = scale^2`` about (cx, cy) at height z."""
    w, v = np.linalg.eigh(cov_xy)
    axes = v * np.sqrt(np.clip(w, 0.0, None)) * scale
    th = np.linspace(0.0, 2 * math.pi, ELLIPSE_POINTS, endpoint=False)
    pts = axes @ np.vstack([np.cos(th), np.sin(th)])
    return [(cx + float(a), cy + float(b), z) for a, b in pts.T]


def scene_of_scenario(scenario: Scenario, ns: int) -> dict[str, Any]:
    """The ``foxglove/map`` SceneUpdate: the flight area's bounds and the mapped walls."""
    (x0, y0, _), (x1, y1, _) = scenario.bounds_min, scenario.bounds_max
    bounds = _line([(x0, y0, 0), (x1, y0, 0), (x1, y1, 0), (x0, y1, 0)], _color(0.6, 0.6, 0.6), LINE_LOOP)
    cubes = []
    for w in scenario.walls:
        (ax, ay), (bx, by) = w.start, w.end
        cubes.append({"pose": _pose((ax + bx) / 2, (ay + by) / 2, w.height / 2, math.atan2(by - ay, bx - ax)),
                      "size": _vec(math.hypot(bx - ax, by - ay), w.thickness, w.height),
                      "color": _color(0.55, 0.45, 0.35, 0.8)})
    return {"deletions": [], "entities": [_entity(ns, "bounds", lines=[bounds]), _entity(ns, "walls", cubes=cubes)]}


def plan_entity(msg: dict[str, Any], ns: int) -> dict[str, Any]:
    """The planned path (line) and dwell points (spheres) of a ``plan`` payload (``topics.PayloadError`` if it
    breaks its schema)."""
    plan = topics.Plan.from_dict(msg)
    green = _color(0.1, 0.8, 0.1)
    path = [q[:3] for q in plan.points("path")]
    return _entity(ns, "plan", lines=[_line(path, green)] if len(path) > 1 else [],
                   spheres=[_sphere(q[:3], 0.3, green) for q in plan.points("dwell_points")])


def estimate_entity(msg: dict[str, Any], ns: int) -> dict[str, Any]:
    """Each estimated source (sphere) and, where its covariance is known, its x-y 1-sigma and 95 % ellipses at
    the source's height (``topics.PayloadError`` if the payload breaks its schema)."""
    estimate = topics.Estimate.from_dict(msg)
    red = _color(0.9, 0.1, 0.1)
    spheres, lines = [], []
    for k, s in enumerate(estimate.sources):
        p = [float(s[c]) for c in ("x", "y", "z")]
        spheres.append(_sphere(p, 0.15, red))
        c = np.array(estimate.covariance_block(k), dtype=float)[:2, :2]
        if not np.all(np.isfinite(c)):
            continue
        c = (c + c.T) / 2
        lines.append(_line(_ellipse(p[0], p[1], p[2], c, 1.0), red, LINE_LOOP, 0.03))
        lines.append(_line(_ellipse(p[0], p[1], p[2], c, math.sqrt(CHI2_95_2D)), _color(0.9, 0.1, 0.1, 0.4),
                           LINE_LOOP, 0.02))
    return _entity(ns, "estimate", spheres=spheres, lines=lines)


class FoxgloveView:
    """Derives the Foxglove messages of each recorded message (``derive``). ``scenario`` gives the walls
    (None: no ``foxglove/map``); ``home`` converts poses of vehicles in ``gps_vehicles``' complement to
    latitude and longitude (None: those get no LocationFix); vehicles in ``gps_vehicles`` have their MAVLink
    recorded and take their LocationFix from ``GLOBAL_POSITION_INT``."""

    def __init__(self, scenario: Scenario | None = None, home: Home | None = None,
                 gps_vehicles: frozenset[str] = frozenset()):
        self.scenario, self.home, self.gps_vehicles = scenario, home, gps_vehicles
        self._scene: dict[str, dict[str, dict[str, Any]]] = {}  # vehicle -> entity id -> entity
        self._next_scene_ns: dict[str, int] = {}  # scene channel -> sim ns of its next periodic update

    def derive(self, channel: str, msg: Any, ns: int) -> list[Message]:
        """The Foxglove messages of recorded message ``msg`` (decoded JSON) on ``channel`` at sim time ``ns``,
        and the scene updates due by then."""
        out: list[Message] = []
        parts = channel.split("/")
        if parts[0] == topics.PREFIX and len(parts) >= 3 and isinstance(msg, dict):
            out += self._radseek(parts[1], "/".join(parts[2:]), msg, ns)
        elif parts[0] == "mavlink" and parts[-1] == "GLOBAL_POSITION_INT" and isinstance(msg, dict):
            vehicle = parts[1] if len(parts) == 3 else topics.DEFAULT_VEHICLE
            if vehicle in self.gps_vehicles:
                out.append(self._gps_fix(vehicle, msg, ns))
        out += self._scenes_due(ns)
        return out

    def _radseek(self, vehicle: str, topic: str, msg: dict[str, Any], ns: int) -> list[Message]:
        try:
            if topic in (topics.POSE, topics.SIM_TRUTH_POSE):
                return self._pose(vehicle, topic == topics.SIM_TRUTH_POSE, msg, ns)
            if topic in (topics.PLAN, topics.ESTIMATE):
                entity = plan_entity(msg, ns) if topic == topics.PLAN else estimate_entity(msg, ns)
                self._scene.setdefault(vehicle, {})[entity["id"]] = entity
                return [self._vehicle_scene(vehicle, ns)]
        except (KeyError, TypeError, ValueError):  # a payload that fails its schema draws nothing
            return []
        return []

    def _pose(self, vehicle: str, truth: bool, msg: dict[str, Any], ns: int) -> list[Message]:
        x, y, z, yaw = (float(msg[k]) for k in ("x", "y", "z", "yaw"))
        child = f"{vehicle}/truth" if truth else vehicle
        out: list[Message] = [
            (f"foxglove/{vehicle}/{'truth_pose' if truth else 'pose'}", "foxglove.PoseInFrame",
             {"timestamp": stamp(ns), "frame_id": MAP_FRAME, "pose": _pose(x, y, z, yaw)}),
            (f"foxglove/{vehicle}/tf", "foxglove.FrameTransform",
             {"timestamp": stamp(ns), "parent_frame_id": MAP_FRAME, "child_frame_id": child,
              "translation": _vec(x, y, z), "rotation": _quat_yaw(yaw)})]
        if not truth and self.home is not None and vehicle not in self.gps_vehicles:
            lat, lon, alt = enu_to_geodetic(self.home, np.array([x, y, z]))
            var = [max(float(msg.get(f"var_{c}", 0.0)), 0.0) for c in "xyz"]
            out.append((f"foxglove/{vehicle}/location", "foxglove.LocationFix", {
                "timestamp": stamp(ns), "frame_id": vehicle, "latitude": lat, "longitude": lon, "altitude": alt,
                "position_covariance": [var[0], 0, 0, 0, var[1], 0, 0, 0, var[2]],
                "position_covariance_type": COVARIANCE_DIAGONAL_KNOWN,
                "heading": yaw_enu_to_ned(yaw) % (2 * math.pi), "metadata": []}))
        return out

    def _gps_fix(self, vehicle: str, m: dict[str, Any], ns: int) -> Message:
        fix: dict[str, Any] = {
            "timestamp": stamp(ns), "frame_id": vehicle, "latitude": m["lat"] / 1e7, "longitude": m["lon"] / 1e7,
            "altitude": m["alt"] / 1000.0, "position_covariance": [0.0] * 9,
            "position_covariance_type": COVARIANCE_UNKNOWN,
            "velocity": _vec(m["vy"] / 100.0, m["vx"] / 100.0, -m["vz"] / 100.0),  # NED cm/s -> ENU m/s
            "metadata": []}
        if m.get("hdg") != HDG_UNKNOWN:
            fix["heading"] = math.radians(m["hdg"] / 100.0)
        return f"foxglove/{vehicle}/location", "foxglove.LocationFix", fix

    def _vehicle_scene(self, vehicle: str, ns: int) -> Message:
        self._next_scene_ns[f"foxglove/{vehicle}/scene"] = ns + int(SCENE_PERIOD_S * 1e9)
        entities = [{**e, "timestamp": stamp(ns)} for e in self._scene[vehicle].values()]
        return f"foxglove/{vehicle}/scene", "foxglove.SceneUpdate", {"deletions": [], "entities": entities}

    def _scenes_due(self, ns: int) -> list[Message]:
        out: list[Message] = []
        if self.scenario is not None and ns >= self._next_scene_ns.get("foxglove/map", 0):
            self._next_scene_ns["foxglove/map"] = ns + int(SCENE_PERIOD_S * 1e9)
            out.append(("foxglove/map", "foxglove.SceneUpdate", scene_of_scenario(self.scenario, ns)))
        for vehicle in self._scene:
            if ns >= self._next_scene_ns[f"foxglove/{vehicle}/scene"]:
                out.append(self._vehicle_scene(vehicle, ns))
        return out
