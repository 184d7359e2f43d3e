"""``radseek view``: an opt-in live view of a flight in Foxglove (WebSocket protocol, foxglove-sdk).

Open Foxglove, "Open connection" → ``ws://127.0.0.1:8765`` (subprotocol ``foxglove.sdk.v1`` or
``foxglove.websocket.v1``: ``launch.ws_relay``). Channels:

- ``/map`` (foxglove.SceneUpdate, frame ``map`` = local ENU): the flight area's bounds and mapped walls
  (from ``--scenario`` or ``--scene``), the vehicle and its estimated track (``pose``), the planned path
  and dwell points (``plan``), each estimated source with its 1-sigma ellipsoid (``estimate``);
- every radseek zenoh JSON topic as it is (``/radseek/<vehicle>/<topic>``, JSON schema from
  ``radseek/topics.py``): plot ``detector/histogram``'s ``counts`` for the spectra, ``pose.x`` etc.

Nothing is started unless you run it; it only subscribes, so it can join or leave a running flight.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time
from pathlib import Path
from typing import Any

from radseek import topics
from radseek_cli.serve import serve_on_session

MAP_HZ = 5.0  # wall Hz at most for /map updates


def _q_yaw(yaw: float):
    from foxglove import messages as m

    return m.Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))


def _pose(x: float, y: float, z: float, yaw: float = 0.0):
    from foxglove import messages as m

    return m.Pose(position=m.Vector3(x=x, y=y, z=z), orientation=_q_yaw(yaw))


def _color(r: float, g: float, b: float, a: float = 1.0):
    from foxglove import messages as m

    return m.Color(r=r, g=g, b=b, a=a)


class MapState:
    """What the map shows, updated from the topics; ``scene()`` builds the SceneUpdate."""

    def __init__(self, bounds: tuple[Any, Any] | None, walls: list[Any]):
        self.bounds, self.walls = bounds, walls
        self.track: list[tuple[float, float, float]] = []
        self.vehicle: tuple[float, float, float, float] | None = None
        self.path: list[list[float]] = []
        self.dwells: list[list[float]] = []
        self.sources: list[tuple[list[float], list[float]]] = []  # (x, y, z), (sx, sy, sz)

    def update(self, topic: str, msg: dict) -> bool:
        """Take one message; True if the map changed."""
        if topic == topics.POSE:
            p = (float(msg["x"]), float(msg["y"]), float(msg["z"]))
            self.vehicle = (*p, float(msg.get("yaw", 0.0)))
            if not self.track or math.dist(self.track[-1], p) > 0.05:
                self.track.append(p)
                del self.track[:-5000]
            return True
        if topic == topics.PLAN:
            try:
                plan = topics.Plan.from_dict(msg)
            except topics.PayloadError:
                return False
            self.path = [q[:3] for q in plan.points("path")]
            self.dwells = [q[:3] for q in plan.points("dwell_points")]
            return True
        if topic == topics.ESTIMATE:
            try:
                est = topics.Estimate.from_dict(msg)
            except topics.PayloadError:
                return False
            out = []
            for k, s in enumerate(est.sources):
                block = est.covariance_block(k)  # row-major 4 x 4 of (x, y, z, cps)
                sig = [math.sqrt(block[i][i]) if math.isfinite(block[i][i]) and block[i][i] > 0 else 0.0
                       for i in range(3)]
                out.append(([float(s["x"]), float(s["y"]), float(s["z"])], sig))
            self.sources = out
            return True
        return False

    def scene(self):
        from foxglove import messages as m

        def line(points, color, kind=m.LinePrimitiveLineType.LineStrip, thickness=0.05):
            return m.LinePrimitive(type=kind, pose=_pose(0, 0, 0), thickness=thickness, scale_invariant=False,
                                   points=[m.Point3(x=p[0], y=p[1], z=p[2]) for p in points], color=color)

        def entity(eid: str, **prims):
            return m.SceneEntity(frame_id="map", id=eid, frame_locked=False, **prims)

        ents = []
        if self.bounds is not None:
            (x0, y0, _), (x1, y1, _) = self.bounds
            ents.append(entity("bounds", lines=[line([(x0, y0, 0), (x1, y0, 0), (x1, y1, 0), (x0, y1, 0)],
                                                     _color(0.6, 0.6, 0.6), m.LinePrimitiveLineType.LineLoop)]))
        cubes = []
        for w in self.walls:
            (ax, ay), (bx, by) = w.start, w.end
            length = math.hypot(bx - ax, by - ay)
            cubes.append(m.CubePrimitive(pose=_pose((ax + bx) / 2, (ay + by) / 2, w.height / 2,
                                                    math.atan2(by - ay, bx - ax)),
                                         size=m.Vector3(x=length, y=w.thickness, z=w.height),
                                         color=_color(0.55, 0.45, 0.35, 0.8)))
        ents.append(entity("walls", cubes=cubes))
        ents.append(entity("track", lines=[line(self.track, _color(0.2, 0.5, 1.0))] if len(self.track) > 1 else []))
        ents.append(entity("path", lines=[line(self.path, _color(0.1, 0.8, 0.1))] if len(self.path) > 1 else []))
        ents.append(entity("dwells", spheres=[m.SpherePrimitive(pose=_pose(*d), size=m.Vector3(x=0.3, y=0.3, z=0.3),
                                                                color=_color(0.1, 0.8, 0.1)) for d in self.dwells]))
        if self.vehicle is not None:
            x, y, z, yaw = self.vehicle
            ents.append(entity("vehicle", cubes=[m.CubePrimitive(pose=_pose(x, y, z, yaw),
                                                                 size=m.Vector3(x=0.5, y=0.3, z=0.15),
                                                                 color=_color(0.1, 0.3, 0.9))]))
        spheres = []
        for (x, y, z), sig in self.sources:
            spheres.append(m.SpherePrimitive(pose=_pose(x, y, z), size=m.Vector3(x=0.15, y=0.15, z=0.15),
                                             color=_color(0.9, 0.1, 0.1)))
            if any(sig):  # the 1-sigma ellipsoid (axis-aligned: diagonal of the covariance)
                spheres.append(m.SpherePrimitive(pose=_pose(x, y, z),
                                                 size=m.Vector3(x=2 * sig[0], y=2 * sig[1], z=2 * max(sig[2], 0.01)),
                                                 color=_color(0.9, 0.1, 0.1, 0.3)))
        ents.append(entity("estimate", spheres=spheres))
        return m.SceneUpdate(deletions=[], entities=ents)


class LiveView:
    """Relays the zenoh topics of ``session`` to a Foxglove WebSocket server and draws ``/map``."""

    def __init__(self, session, *, host: str = "127.0.0.1", port: int = 8765, bounds=None, walls=(),
                 key: str = topics.all_keys()):
        import foxglove
        from foxglove.channels import SceneUpdateChannel

        from launch.ws_relay import SubprotocolRelay

        # the SDK's server on a loopback port of its own; the relay on the public one accepts foxglove.websocket.v1
        # clients (Lichtblick, older Foxglove, the reference client) as well as foxglove.sdk.v1 ones
        self.server = foxglove.start_server(name="radseek", host="127.0.0.1", port=0)
        try:
            self.relay = SubprotocolRelay(host, port, self.server.port)
        except BaseException:
            self.server.stop()
            raise
        self.port = self.relay.port
        self._map = SceneUpdateChannel("/map")
        self._state = MapState(bounds, list(walls))
        self._channels: dict[str, Any] = {}
        self._lock = threading.Lock()
        self._last_map = 0.0
        self._publish_map()
        self._sub = session.declare_subscriber(key, self._on_sample)

    def _channel(self, key: str, topic: str):
        ch = self._channels.get(key)
        if ch is None:
            from foxglove import Channel, Schema

            cls = topics.PAYLOADS.get(topic)
            schema = None if cls is None else Schema(name=f"radseek.{cls.__name__}", encoding="jsonschema",
                                                     data=json.dumps(topics.json_schema(cls)).encode())
            ch = self._channels[key] = Channel("/" + key, schema=schema, message_encoding="json")
        return ch

    def _on_sample(self, sample) -> None:
        key = str(sample.key_expr)
        topic = key.split("/", 2)[2] if key.count("/") >= 2 else key
        if topic == topics.RAW_FRAME or topic not in topics.PAYLOADS:
            return  # binary board frames are not drawn
        data = sample.payload.to_bytes()
        try:
            msg = json.loads(data)
        except ValueError:
            return
        with self._lock:
            self._channel(key, topic).log(data)
            if self._state.update(topic, msg) and time.monotonic() - self._last_map >= 1.0 / MAP_HZ:
                self._publish_map()

    def _publish_map(self) -> None:
        self._last_map = time.monotonic()
        self._map.log(self._state.scene())

    def close(self) -> None:
        self._sub.undeclare()
        self.relay.close()
        self.server.stop()


def _load_area(args) -> tuple[Any, list[Any]]:
    if args.scenario is not None:
        from radseek_io.dataset import read_scenario

        sc = read_scenario(Path(args.scenario))
        return (tuple(sc.bounds_min), tuple(sc.bounds_max)), list(sc.walls)
    from detector_fw_sim.scene import load_scene

    sc = load_scene(args.scene).scenario()
    return (tuple(sc.bounds_min), tuple(sc.bounds_max)), list(sc.walls)


def main(argv: list[str] | None = None) -> int:
    from radseek.zenoh_session import add_arguments

    p = argparse.ArgumentParser(prog="radseek view", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    area = p.add_mutually_exclusive_group()
    area.add_argument("--scenario", help="scenario.json whose bounds and walls are drawn")
    area.add_argument("--scene", default="default", help="scene (bundled name or file) to draw (default: default)")
    p.add_argument("--host", default="127.0.0.1", help="address of the Foxglove WebSocket server (default loopback)")
    p.add_argument("--port", type=int, default=8765, help="its port (default 8765, Foxglove's; 0 = any free port)")
    p.add_argument("--duration", type=float, help="wall seconds to serve (default: until Ctrl-C / SIGTERM)")
    add_arguments(p)
    args = p.parse_args(argv)
    if not 0 <= args.port <= 65535:
        p.error(f"--port {args.port} is not a port number")
    try:
        import foxglove  # noqa: F401 - opt-in dependency
    except ImportError:
        print("radseek view: needs the Foxglove SDK: pip install 'radseek[view]' (foxglove-sdk)", file=sys.stderr)
        return 2
    try:
        bounds, walls = _load_area(args)
    except Exception as exc:  # noqa: BLE001 - any unreadable map is reported the same way
        print(f"radseek view: cannot read the map: {exc}", file=sys.stderr)
        return 2
    return serve_on_session(
        "radseek view", args,
        lambda session: LiveView(session, host=args.host, port=args.port, bounds=bounds, walls=walls),
        Exception,  # foxglove raises its own error types for a taken port
        lambda exc: f"cannot serve on {args.host}:{args.port} ({exc}): choose another with --port",
        started=lambda view: f"radseek view: Foxglove WebSocket on ws://{args.host}:{view.port} (open it in Foxglove)",
        stop=LiveView.close)
