"""Lockstep: the vehicle does not step sim time past what the mission process allows (mission/lockstep).

A real vehicle loop (in a thread) and a real zenoh router; this test plays the mission by publishing
``mission/lockstep`` itself and watches ``sim/clock`` and ``pose``. Every assertion is on sim time and
on events (messages seen, commands answered); wall time only bounds the waiting."""

import threading
import time

import pytest
from pymavlink.dialects.v20 import common as M

from radseek import topics
from radseek.zenoh_session import open_session
from vehicle_sim.harness import Gcs, VehicleThread, free_udp_port
from vehicle_sim.lockstep import LockstepGate
from vehicle_sim.vehicle import VehicleConfig

WAIT_S = 60.0


def test_payload_validates_until_and_flags():
    msg = topics.MissionLockstep(t=1.0, until=1.1)
    assert topics.MissionLockstep.from_bytes(msg.to_bytes()) == msg
    with pytest.raises(topics.PayloadError, match="until"):
        topics.MissionLockstep.from_dict({"t": 1.0, "until": 0.5})
    with pytest.raises(topics.PayloadError, match="busy"):
        topics.MissionLockstep.from_dict({"t": 1.0, "until": 1.0, "busy": 1})
    assert topics.PAYLOADS[topics.MISSION_LOCKSTEP] is topics.MissionLockstep


def test_gate_holds_at_zero_never_goes_back_and_detaches():
    gate = LockstepGate(timeout_s=100.0)
    assert gate.limit() == 0.0  # attached from the start: hold at t = 0 until the mission acks
    gate.offer(topics.MissionLockstep(t=0.5, until=0.6))
    gate.offer(topics.MissionLockstep(t=0.4, until=0.5))  # a late repeat does not take time back
    assert gate.limit() == 0.6
    gate.offer(topics.MissionLockstep(t=0.6, until=0.6, busy=True))
    assert gate.busy and gate.limit() == 0.6
    gate.offer(topics.MissionLockstep(t=0.6, until=0.7, attached=False))
    assert gate.limit() is None and "left lockstep" in gate.released
    gate.close()


class _Watch:
    """Collects sim/clock and pose times."""

    def __init__(self, session):
        self.clock: list[float] = []
        self.poses: list[float] = []
        self.lock = threading.Lock()
        self._subs = [session.declare_subscriber(topics.key(topics.SIM_CLOCK), self._on_clock),
                      session.declare_subscriber(topics.key(topics.POSE), self._on_pose)]

    def _on_clock(self, s):
        with self.lock:
            self.clock.append(topics.SimClock.from_bytes(s.payload.to_bytes()).t)

    def _on_pose(self, s):
        with self.lock:
            self.poses.append(topics.Pose.from_bytes(s.payload.to_bytes()).t)

    def n(self) -> int:
        with self.lock:
            return len(self.clock)

    def latest(self) -> float:
        with self.lock:
            return self.clock[-1] if self.clock else -1.0

    def max(self) -> float:
        with self.lock:
            return max(self.clock, default=-1.0)

    def wait(self, cond, what: str) -> None:
        deadline = time.monotonic() + WAIT_S
        while not cond():
            assert time.monotonic() < deadline, f"timed out waiting for {what} (clock at {self.latest()})"
            time.sleep(0.01)

    def held_for(self, n_msgs: int) -> float:
        """Wait until ``n_msgs`` more clock messages came (the held vehicle repeats its time at 10 Hz
        wall) and return the largest time seen meanwhile."""
        n0 = self.n()
        self.wait(lambda: self.n() >= n0 + n_msgs, f"{n_msgs} more sim/clock messages")
        return self.max()

    def close(self):
        for s in self._subs:
            s.undeclare()


def test_vehicle_holds_the_clock_while_the_mission_is_busy(router):
    api, gcs = free_udp_port(), free_udp_port()
    cfg = VehicleConfig(api_port=api, gcs_port=gcs, api_local_port=0, gcs_local_port=0, speedup=100.0,
                        zenoh=True, zenoh_connect=router, lockstep=True, lockstep_timeout_s=5.0)
    with open_session(connect=router) as session, Gcs(api) as mav:
        watch = _Watch(session)
        pub = session.declare_publisher(topics.key(topics.MISSION_LOCKSTEP))

        def say(t, until, busy=False):
            pub.put(topics.MissionLockstep(t=t, until=until, busy=busy).to_bytes())

        with VehicleThread(cfg) as vehicle:
            # keep the vehicle attached (a message well inside the 5 s watchdog) while holding at t = 0
            watch.wait(lambda: watch.n() > 0, "the vehicle's first sim/clock")
            say(0.0, 0.0, busy=True)
            assert watch.held_for(10) == 0.0  # no ack yet: not one step

            # ack up to 1.0 s: it steps there exactly, publishes its pose there, and stops
            say(0.0, 1.0)
            watch.wait(lambda: watch.latest() >= 1.0 - 1e-9, "t = 1.0")
            say(1.0, 1.0, busy=True)  # the mission computes on the frame ending at 1.0
            assert abs(watch.held_for(10) - 1.0) < 1e-9
            say(1.0, 1.0, busy=True)
            with watch.lock:
                assert any(abs(t - 1.0) < 1e-9 for t in watch.poses), watch.poses[-5:]

            # MAVLink is answered while the clock is held: a command is acked, heartbeats keep coming
            mav.wait_vehicle()
            assert mav.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
            mav.recv("HEARTBEAT")
            say(1.0, 1.0, busy=True)
            assert abs(watch.held_for(5) - 1.0) < 1e-9
            assert vehicle.nav.armed and abs(vehicle.t - 1.0) < 1e-9  # applied at the held sim time

            # the next ack lets it step one more frame, and no further
            say(1.0, 1.1)
            watch.wait(lambda: watch.latest() >= 1.1 - 1e-9, "t = 1.1")
            say(1.1, 1.1, busy=True)
            assert abs(watch.held_for(5) - 1.1) < 1e-9

            # the mission stops talking (killed): after the watchdog the vehicle runs free again
            watch.wait(lambda: watch.latest() > 2.0, "the vehicle to run free after the watchdog")
            assert vehicle.lockstep.released and "mission gone" in vehicle.lockstep.released
        watch.close()
