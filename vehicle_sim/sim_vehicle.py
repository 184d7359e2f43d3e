"""The mock autopilot's physics, stepped: navigator, odometry, battery, failsafes and geofence, no sockets.

ArduPilot's ``SIM_Aircraft`` pattern: ``step(dt, link_age)`` advances the simulated vehicle one fixed sim
step and returns what happened (items reached, texts for STATUSTEXT, mode changes). The MAVLink vehicle
process (``vehicle_sim.vehicle.Vehicle``) is this plus its links; the in-process world
(``vehicle_sim.world``) is this plus the detector board, so ``radseek run`` and the campaigns fly one
vehicle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from pymavlink.dialects.v20 import common as M

from vehicle_sim import battery as battery_model
from vehicle_sim.failsafe import Action, Failsafe
from vehicle_sim.navigator import Mode, Navigator
from vehicle_sim.odometry import Odometry

if TYPE_CHECKING:
    from vehicle_sim.vehicle import VehicleConfig


@dataclass(frozen=True)
class SimEvent:
    """Something a step did: ``reached`` (data: the item's seq), ``text`` (data: (text, MAV_SEVERITY)),
    ``mode`` (data: the new ``Mode``)."""

    kind: str
    data: Any


class SimVehicle:
    """One simulated multicopter: the state ``Vehicle`` flies and reports, with nothing of MAVLink."""

    def __init__(self, cfg: VehicleConfig):
        self.cfg = cfg
        self.home, self.fence = cfg.home, cfg.fence
        self.nav = Navigator(cfg.home, cfg.limits, cfg.nav)
        if any(cfg.start_xy):
            self.nav.pos[:2] = cfg.start_xy
            self.nav.target = self.nav.pos.copy()
            self.nav.launch_xy = np.asarray(cfg.start_xy, dtype=float)
        self.odo = Odometry(cfg.odometry, seed=cfg.seed)
        self.battery = 1.0
        self.failsafe = Failsafe(cfg.failsafe, cfg.battery.low_threshold, cfg.battery.critical_threshold)
        self.failsafe_active = False
        self._breached = False
        self.t = 0.0
        self._yaw_rate = 0.0
        self.steps = 0

    def step(self, dt: float, link_age: float | None) -> list[SimEvent]:
        """Advance ``dt`` sim seconds; ``link_age`` is the wall seconds since the ground link last spoke (None:
        never). Returns the step's events in order."""
        nav = self.nav
        events: list[SimEvent] = []
        yaw0 = nav.yaw
        dist = nav.step(self.t, dt)
        self.t += dt
        self._yaw_rate = math.remainder(nav.yaw - yaw0, 2 * math.pi) / dt
        self.odo.advance(dist)
        speed = float(np.linalg.norm(nav.vel))
        self.battery = battery_model.drain(self.battery, dt, nav.armed, nav.in_air, speed, self.cfg.battery)
        for ev in self.failsafe.update(self.t, link_age is not None, link_age or 0.0, self.battery, nav.in_air):
            self.failsafe_active = ev.action is not Action.NONE
            if ev.action is Action.HOLD:
                nav.hold()
            elif ev.action is Action.RTL:
                nav.rtl()
            elif ev.action is Action.LAND:
                nav.land()
            events.append(SimEvent("text", (ev.text, ev.severity)))  # announced once acted upon
        events += self._check_fence()
        for kind, data in nav.events:
            events.append(SimEvent(kind, (str(data), M.MAV_SEVERITY_INFO) if kind == "text" else data))
        nav.events.clear()
        self.steps += 1
        return events

    def _check_fence(self) -> list[SimEvent]:
        """Breach check in flight (offboard velocity, drift): leaving the fence -> HOLD, announced once."""
        nav = self.nav
        inside = not nav.in_air or self.fence.contains(nav.pos, tol=0.5)
        if inside:
            self._breached = False
            return []
        if self._breached:
            return []
        self._breached = True
        if nav.mode not in (Mode.RTL, Mode.LAND):
            nav.hold()
        return [SimEvent("text", (f"Geofence breached at {np.round(nav.pos, 1).tolist()} m, holding",
                                  M.MAV_SEVERITY_CRITICAL))]

    def truth(self) -> tuple[np.ndarray, float]:
        """The true position (ENU m) and yaw (rad): the estimate the vehicle flies on, minus its drift."""
        return self.odo.truth_from_estimate(self.nav.pos, self.nav.yaw)

    def estimate(self) -> tuple[np.ndarray, float]:
        """The estimated position and yaw the vehicle flies on (what ``pose`` publishes)."""
        return self.nav.pos, self.nav.yaw
