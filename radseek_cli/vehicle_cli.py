"""``radseek vehicle``: the mock autopilot as its own process (MAVLink 2 over UDP on the SITL ports).

With no arguments it sends to 127.0.0.1:14540 (MAVSDK ``udpin://0.0.0.0:14540``) and 127.0.0.1:14550
(QGroundControl / MAVProxy ``--master=udpin:127.0.0.1:14550``), answers on the same sockets, runs in
real time and publishes its clock and poses on zenoh (router at tcp/127.0.0.1:7447, waited for in the
background). A router that refuses its zenoh credentials stops it at once: exit 1 with a one-line reason
naming its user and the router's endpoint.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys

from radseek import zenoh_session


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="radseek vehicle", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    g = p.add_argument_group("MAVLink link")
    g.add_argument("--api-port", type=int, default=14540, help="remote API/offboard port (default 14540)")
    g.add_argument("--gcs-port", type=int, default=14550, help="remote GCS port (default 14550)")
    g.add_argument("--api-local-port", type=int, default=14580, help="local API socket port (0 = any; default 14580)")
    g.add_argument("--gcs-local-port", type=int, default=18570, help="local GCS socket port (0 = any; default 18570)")
    g.add_argument("--bind", default="127.0.0.1", help="local address (default loopback only)")
    g.add_argument("--remote-host", default="127.0.0.1", help="where the SITL ports are (default 127.0.0.1)")
    g.add_argument("--sysid", type=int, default=1, help="MAVLink system id (default 1)")
    g.add_argument("--signing-key", metavar="FILE",
                   help="MAVLink 2 signing key file (64 hex digits, or a passphrase hashed with SHA-256); "
                        "unsigned or wrongly signed messages are then refused")
    g.add_argument("--drop-rate", type=float, default=0.0, help="fault injection: drop each datagram with this "
                                                                "probability in [0, 1) (default 0)")
    s = p.add_argument_group("simulation")
    s.add_argument("--speedup", type=float, default=1.0, help="sim seconds per wall second (default 1)")
    s.add_argument("--dt", type=float, default=0.05, help="fixed sim step, s (default 0.05)")
    s.add_argument("--seed", type=int, default=0, help="seed of the odometry drift and fault injection (default 0)")
    s.add_argument("--home", default="47.397742,8.545594,488.0", help="home lat,lon,alt_amsl (default PX4 SITL's)")
    s.add_argument("--bounds", help="geofence xmin,ymin,zmin,xmax,ymax,zmax in local ENU m "
                                    "(write --bounds=-5,... for negative values; "
                                    "default: from --scene, else -1000,-1000,0,1000,1000,120, "
                                    "wide enough for MAVSDK's examples)")
    s.add_argument("--start", default="0,0", metavar="X,Y",
                   help="launch point in local ENU m (where RTL lands; default 0,0, the home; vehicles of a team "
                        "share the home and start apart)")
    s.add_argument("--scene", help="scene (bundled name or TOML/JSON file): its x-y bounds plus a 1 m margin "
                                   "become the geofence, 0-10 m above its top")
    s.add_argument("--wall-fence", action="store_true",
                   help="with --scene: its mapped walls become exclusion fences (footprint + --wall-margin), so "
                        "a mission item, go-to, orbit or offboard setpoint inside a wall is refused")
    s.add_argument("--wall-margin", type=float, default=0.3,
                   help="clearance around each wall for --wall-fence, m (default 0.3, the vehicle radius)")
    s.add_argument("--max-speed", type=float, default=3.0, help="horizontal speed limit, m/s (default 3)")
    s.add_argument("--max-accel", type=float, default=2.0, help="acceleration limit, m/s^2 (default 2)")
    s.add_argument("--battery-endurance", type=float, default=1200.0,
                   help="hover endurance on a full battery, sim s (default 1200)")
    s.add_argument("--drift", type=float, default=0.03, help="odometry drift density, m/sqrt(m) (default 0.03)")
    s.add_argument("--lockstep", action=argparse.BooleanOptionalAction, default=False,
                   help="hold sim time while the mission process computes (it publishes mission/lockstep; "
                        "`radseek run` turns this on). Off by default: MAVSDK examples or a GCS alone run free")
    s.add_argument("--lockstep-timeout", type=float, default=5.0,
                   help="wall s without a mission/lockstep message before lockstep is released and the "
                        "vehicle runs free (mission gone; default 5; 60 before the first message)")
    f = p.add_argument_group("failsafes")
    f.add_argument("--link-loss-timeout", type=float, default=5.0,
                   help="s without any GCS message before holding (link clock, default 5)")
    f.add_argument("--link-loss-hold", type=float, default=10.0,
                   help="sim s to hold after link loss before returning to launch (default 10)")
    f.add_argument("--no-failsafe", action="store_true", help="disable all failsafes")
    p.add_argument("--no-zenoh", action="store_true", help="do not publish on zenoh")
    p.add_argument("--duration", type=float, help="stop after this many sim seconds")
    p.add_argument("-v", "--verbose", action="store_true", help="log every command and transition")
    zenoh_session.add_arguments(p)
    return p


def scene_fence(scene: str):
    """Geofence around a detector scene's bounds (the scene module is the other engineer's seam)."""
    from detector_fw_sim.scene import load_scene
    from vehicle_sim.geofence import Geofence

    b = load_scene(scene).bounds
    return Geofence(b.min[0] - 1.0, b.min[1] - 1.0, 0.0, b.max[0] + 1.0, b.max[1] + 1.0, max(b.max[2], 0.0) + 10.0)


def config_from_args(args: argparse.Namespace):
    from radseek.coordinates import Home
    from vehicle_sim.battery import BatteryParams
    from vehicle_sim.failsafe import FailsafeParams
    from vehicle_sim.geofence import Geofence
    from vehicle_sim.link import load_signing_key
    from vehicle_sim.motion import MotionLimits
    from vehicle_sim.odometry import OdometryParams
    from vehicle_sim.vehicle import VehicleConfig

    lat, lon, alt = (float(v) for v in args.home.split(","))
    if args.bounds:
        fence = Geofence.parse(args.bounds)
    elif args.scene:
        fence = scene_fence(args.scene)
    else:
        fence = Geofence()
    if args.wall_fence:
        if not args.scene:
            raise ValueError("--wall-fence needs --scene (the walls come from the scene)")
        if not 0 <= args.wall_margin <= 10:
            raise ValueError(f"--wall-margin {args.wall_margin} must be in [0, 10] m")
        from detector_fw_sim.scene import load_scene
        from vehicle_sim.geofence import wall_zones

        fence = fence.with_zones(wall_zones(load_scene(args.scene).walls, args.wall_margin))
    return VehicleConfig(
        bind_host=args.bind, remote_host=args.remote_host, api_port=args.api_port, gcs_port=args.gcs_port,
        api_local_port=args.api_local_port, gcs_local_port=args.gcs_local_port, sysid=args.sysid,
        speedup=args.speedup, dt=args.dt, seed=args.seed, home=Home(lat, lon, alt),
        fence=fence,
        limits=MotionLimits(max_speed_xy=args.max_speed, max_accel=args.max_accel),
        odometry=OdometryParams(sigma_xy=args.drift, sigma_z=args.drift / 3),
        battery=BatteryParams(hover_endurance_s=args.battery_endurance),
        failsafe=FailsafeParams(args.link_loss_timeout, args.link_loss_hold, enabled=not args.no_failsafe),
        signing_key=load_signing_key(args.signing_key) if args.signing_key else None,
        drop_rate=args.drop_rate, zenoh=not args.no_zenoh, zenoh_config=args.zenoh_config,
        zenoh_connect=args.connect, vehicle_name=args.vehicle_name,
        lockstep=args.lockstep, lockstep_timeout_s=args.lockstep_timeout, start_xy=_start(args.start, fence),
    )


def _start(text: str, fence) -> tuple[float, float]:
    """--start X,Y as a point inside the geofence (ValueError otherwise)."""
    import numpy as np

    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--start {text!r} must be X,Y in metres") from None
    if not fence.contains(np.array([x, y, 0.0]), tol=0.0):
        raise ValueError(f"--start {x:g},{y:g} is outside the geofence")
    return x, y


def _bind_problem(args: argparse.Namespace) -> str | None:
    """Which local UDP port could not be bound, and the flag that moves it (None if both bind)."""
    import socket

    for port, flag in ((args.api_local_port, "--api-local-port"), (args.gcs_local_port, "--gcs-local-port")):
        if port == 0:
            continue
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind((args.bind, port))
            except OSError as exc:
                return (f"UDP port {port} on {args.bind} is in use ({exc.strerror}): another vehicle or SITL? "
                        f"Stop it, or choose another port with {flag} PORT (0 = any free port)")
    return None


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, stream=sys.stderr,
                        format="%(asctime)s vehicle %(levelname)s %(message)s")
    from vehicle_sim.vehicle import Vehicle

    try:
        cfg = config_from_args(args)
        vehicle = Vehicle(cfg)
    except OSError as exc:
        print(f"radseek vehicle: {_bind_problem(args) or exc}", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"radseek vehicle: {exc}", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, lambda *_: vehicle.stop())
    ep_api, ep_gcs = vehicle.link.endpoints
    print(f"vehicle ready: MAVLink 2 api {ep_api.local_address[1]}->{cfg.api_port}, "
          f"gcs {ep_gcs.local_address[1]}->{cfg.gcs_port}, speedup {cfg.speedup:g}"
          f"{', signed' if cfg.signing_key else ''}", flush=True)
    try:
        vehicle.run(max_sim_time=args.duration)
    except KeyboardInterrupt:
        pass
    s = vehicle.link.stats
    print(f"vehicle stopped at t={vehicle.t:.1f} s: rx {s.rx_packets} tx {s.tx_packets} bad {s.bad_data} "
          f"refused-signature {s.rejected_signature} dropped-rx {s.dropped_rx} dropped-tx {s.dropped_tx}", flush=True)
    if vehicle.lockstep is not None:
        g = vehicle.lockstep
        print(f"lockstep: {g.messages} mission/lockstep messages, held {vehicle.stats['lockstep_held_wall_s']:.1f} s "
              f"wall ({vehicle.stats['lockstep_pauses']} pauses > 1 s), "
              f"{'released: ' + g.released if g.released else 'engaged to the end'}", flush=True)
    if vehicle.zenoh_refused is not None:  # the last line: what `radseek run` quotes
        print(f"radseek vehicle: {vehicle.zenoh_refused}: stopped (a vehicle its stack cannot hear must not fly on)",
              file=sys.stderr, flush=True)
        return 1
    return 0
