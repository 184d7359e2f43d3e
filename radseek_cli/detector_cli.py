"""``radseek detector``: the emulated 32-channel spectroscopy board as a zenoh process.

Publishes ``radseek/<vehicle>/detector/raw`` (binary board frames, docs/frame-format.md),
``detector/histogram`` (decoded JSON) at 10 Hz sim time and ``detector/status`` at 1 Hz; reads the true
pose from ``sim/truth_pose`` (or ``--pose``). There is one clock owner: ``--clock zenoh`` follows the vehicle's
``sim/clock``; ``--clock own`` runs its own sim clock at ``--speedup`` (1 = real time) and publishes it;
``--clock auto`` (default) is ``own`` with a fixed ``--pose`` (no vehicle) and ``zenoh`` otherwise, so that
``radseek router``, ``radseek detector`` and ``radseek vehicle`` started by hand, in any order, share the
vehicle's clock (two clocks made the detector's poses stale forever, silently).

With no true pose for ``--stale-after`` sim seconds, frames keep coming at 10 Hz but carry zero counts
and the STALE_POSE flag: the emulator never invents data. A restarted process continues the frame
sequence from board time (= sim time); its first histogram carries FLAG_GAP.

Examples::

    radseek router &
    radseek detector --pose 1,2,1.5,0          # standalone demo at real time
    radseek detector --clock zenoh             # in a mission: the vehicle owns time and pose
    radseek detector --corrupt-rate 0.05 --dropout 30:2   # fault injection
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
import time

from detector_fw_sim.detector_process import DetectorConfig, DetectorProcess, FaultConfig
from radseek import topics
from radseek.simclock import ClockPublisher, FreeRunningClock, ZenohClock
from radseek.zenoh_session import OPEN_ERRORS, add_arguments, session_from_args


def _floats(text: str, n: int, what: str) -> tuple[float, ...]:
    parts = text.split(",") if n > 1 else [text]
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{what} must be {n} comma-separated numbers, got {text!r}") from None
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise argparse.ArgumentTypeError(f"{what} must be {n} finite comma-separated numbers, got {text!r}")
    return vals


def _pose(text: str) -> tuple[float, ...]:
    return _floats(text, 4, "--pose x,y,z,yaw")


def _dropout(text: str) -> tuple[float, float]:
    t0, _, d = text.partition(":")
    try:
        start, dur = float(t0), float(d)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--dropout must be T0:DURATION in sim seconds, got {text!r}") from None
    if not (math.isfinite(start) and math.isfinite(dur) and dur > 0):
        raise argparse.ArgumentTypeError(f"--dropout needs a finite T0 and a DURATION > 0, got {text!r}")
    return start, dur


def _rate(text: str) -> float:
    v = _floats(text, 1, "rate")[0]
    if not 0 <= v <= 1:
        raise argparse.ArgumentTypeError(f"a per-frame probability must be in [0, 1], got {text!r}")
    return v


def _positive(text: str) -> float:
    v = _floats(text, 1, "value")[0]
    if v <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return v


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="radseek detector", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", metavar="FILE", help="scene TOML/JSON (default: the embedded default scene)")
    p.add_argument("--seed", type=int, default=0, help="seed of the count draws and injected faults (default 0)")
    p.add_argument("--clock", choices=("auto", "own", "zenoh"), default="auto",
                   help="own: run and publish sim/clock; zenoh: follow the vehicle's sim/clock; auto (default): "
                        "own with --pose, else zenoh")
    p.add_argument("--speedup", type=_positive, default=1.0, help="--clock own: sim s per wall s (default 1)")
    p.add_argument("--pose", type=_pose, metavar="X,Y,Z,YAW", help="fixed true pose (m, rad) instead of sim/truth_pose")
    p.add_argument("--stale-after", type=_positive, default=0.5, metavar="S",
                   help="flag frames STALE_POSE when no true pose arrived for S sim seconds (default 0.5)")
    p.add_argument("--until", type=_positive, metavar="T", help="stop at sim time T (default: run until stopped)")
    p.add_argument("--truth-wait", type=float, default=0.0, metavar="S",
                   help="wait up to S wall seconds for the true pose at a frame's end before drawing it (lockstep "
                        "runs: the pose and the clock may arrive in either order; default 0: do not wait)")
    f = p.add_argument_group("fault injection")
    f.add_argument("--corrupt-rate", type=_rate, default=0.0, metavar="P",
                   help="flip 1-3 bytes of a raw frame with probability P (consumers reject it by CRC)")
    f.add_argument("--truncate-rate", type=_rate, default=0.0, metavar="P",
                   help="cut a raw frame short with probability P")
    f.add_argument("--dropout", type=_dropout, action="append", default=[], metavar="T0:DURATION",
                   help="send no frames during this sim interval (repeatable)")
    add_arguments(p)
    return p


#: wall s between checks for frames without a fresh pose
STALE_WATCH_S = 10.0


def _warn_when_stale(proc: DetectorProcess, stop: threading.Event, args: argparse.Namespace) -> None:
    """Say so, every :data:`STALE_WATCH_S` wall seconds, while most frames go out STALE_POSE (zero counts): no
    true pose is arriving on this process's clock, and nothing downstream can record a measurement."""
    frames, stale = proc.counters.frames, proc.counters.stale_frames
    while not stop.wait(STALE_WATCH_S):
        df, ds = proc.counters.frames - frames, proc.counters.stale_frames - stale
        frames, stale = proc.counters.frames, proc.counters.stale_frames
        if df > 0 and ds > 0.5 * df:
            fix = ("start `radseek vehicle` on the same router" if args.clock == "zenoh" else
                   "a vehicle runs its own clock: restart this detector with --clock zenoh (or without --clock)")
            print(f"radseek detector: WARNING: {ds} of the last {df} frames had no true pose within "
                  f"{args.stale_after:g} sim s (sent STALE_POSE with zero counts, t = {proc.clock.now():.1f} s): "
                  f"{fix}", file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        topics.key(topics.HISTOGRAM, args.vehicle_name)
    except ValueError as exc:
        print(f"radseek detector: --vehicle-name: {exc}", file=sys.stderr)
        return 2
    from detector_fw_sim.emulator import DetectorEmulator  # heavy: physics tables
    from detector_fw_sim.scene import SceneError, load_scene

    try:
        scene = load_scene(args.scene)
    except (SceneError, OSError) as exc:
        print(f"radseek detector: {exc}", file=sys.stderr)
        return 2
    emulator = DetectorEmulator(scene, seed=args.seed)
    try:
        session = session_from_args(args, "detector")
    except OPEN_ERRORS as exc:
        print(f"radseek detector: {exc}", file=sys.stderr)
        return 1
    config = DetectorConfig(
        vehicle=args.vehicle_name,
        stale_after_s=args.stale_after,
        truth_wait_wall_s=max(args.truth_wait, 0.0),
        fixed_pose=args.pose,
        until=args.until,
        seed=args.seed,
        faults=FaultConfig(args.corrupt_rate, args.truncate_rate, tuple(args.dropout)),
    )
    stop = threading.Event()
    clock_thread = None
    if args.clock == "auto":
        args.clock = "own" if args.pose is not None else "zenoh"
    if args.clock == "own":
        clock = FreeRunningClock(args.speedup)
        pub = ClockPublisher(session, args.vehicle_name, args.speedup)
        step_wall = max(0.002, 0.02 / args.speedup)  # every 20 ms sim (every 2 ms wall at most)

        def tick() -> None:
            while not stop.wait(step_wall):
                pub.publish(clock.now())

        clock_thread = threading.Thread(target=tick, name="sim-clock", daemon=True)
    else:
        clock = ZenohClock(session, args.vehicle_name)
        print(f"radseek detector: waiting for {topics.key(topics.SIM_CLOCK, args.vehicle_name)}", flush=True)
        waited = 0
        while not clock.wait_started(1.0):
            waited += 1
            if waited % 10 == 0:
                print(f"radseek detector: still waiting for the vehicle's clock after {waited} s: start "
                      f"`radseek vehicle` (same router), or give --pose X,Y,Z,YAW to run alone on its own clock",
                      flush=True)
    proc = DetectorProcess(session, clock, emulator, config)
    proc.stop_event = stop
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    if clock_thread is not None:
        clock_thread.start()
    print(f"radseek detector: publishing {topics.key('detector/*', args.vehicle_name)} at 10 Hz sim time "
          f"(clock {args.clock}, speedup {clock.speedup:g}, from t={clock.now():.2f} s)", flush=True)
    wall0 = time.monotonic()
    threading.Thread(target=_warn_when_stale, args=(proc, stop, args), name="stale-watch", daemon=True).start()
    try:
        c = proc.run()
    finally:
        stop.set()
        proc.close()
        session.close()
    print(f"radseek detector: stopped after {time.monotonic() - wall0:.1f} s wall: {c.frames} frames, "
          f"{c.published} histograms, {c.stale_frames} stale, {c.rejected} rejected by the driver, "
          f"{c.dropout_frames} in drop-outs, {c.gaps} gaps, {c.bad_pose_msgs} bad pose messages, "
          f"{c.pose_waits_given_up} made without the true pose at their end", flush=True)
    return 0
