"""Pure failsafe policy: link loss -> hold, then return to launch; low battery -> return to launch;
critical battery -> land. Each transition fires once and is announced (STATUSTEXT by the caller).

``link_age`` is measured on the link's own clock: the ground station is a real-time peer that sends
heartbeats at 1 Hz of wall time, so at a sim speed-up N a sim-time timeout would fire N times too
early. Everything else (the hold before RTL) is in sim seconds. Every event carries the sim time it fired
at and the link age that caused it, and ``history`` keeps them all, so a test or a log can check the
transitions against sim time instead of the wall clock.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from enum import Enum


class Action(Enum):
    NONE = "none"
    HOLD = "hold"
    RTL = "rtl"
    LAND = "land"


@dataclass(frozen=True)
class FailsafeParams:
    link_loss_timeout_s: float = 5.0  # s of link clock without any GCS message, (0, 600] [COM_DL_LOSS_T]
    link_loss_hold_s: float = 10.0  # sim s to hold before returning to launch, [0, 600]
    enabled: bool = True


@dataclass(frozen=True)
class Event:
    action: Action
    text: str
    severity: int  # MAV_SEVERITY
    t: float = 0.0  # sim time at which it fired
    link_age: float = 0.0  # link-clock seconds since the last GCS message, when it fired


class Failsafe:
    """Tracks which failsafes have fired; ``update`` returns the new events (usually none)."""

    def __init__(self, params: FailsafeParams, low: float, critical: float):
        self.params, self.low, self.critical = params, low, critical
        self.link_lost_since: float | None = None
        self._rtl_for_link = False
        self._battery_level = 0  # 0 ok, 1 low fired, 2 critical fired
        self.history: list[Event] = []  # every event returned by ``update``, in order

    def update(self, t: float, link_seen: bool, link_age: float, battery: float, in_air: bool) -> list[Event]:
        events: list[Event] = []
        if not self.params.enabled:
            return events
        if link_seen and link_age > self.params.link_loss_timeout_s:
            if self.link_lost_since is None:
                self.link_lost_since = t
                if in_air:
                    events.append(Event(Action.HOLD, f"Failsafe: link lost for {link_age:.1f} s, holding", 2))
            elif (in_air and not self._rtl_for_link
                  and t - self.link_lost_since >= self.params.link_loss_hold_s):
                self._rtl_for_link = True
                events.append(Event(Action.RTL, "Failsafe: link still lost, returning to launch", 2))
        elif self.link_lost_since is not None:
            self.link_lost_since = None
            self._rtl_for_link = False
            events.append(Event(Action.NONE, "Link regained", 5))
        if in_air:
            if battery <= self.critical and self._battery_level < 2:
                self._battery_level = 2
                events.append(Event(Action.LAND, f"Failsafe: battery critical ({battery:.0%}), landing", 1))
            elif battery <= self.low and self._battery_level < 1:
                self._battery_level = 1
                events.append(Event(Action.RTL, f"Failsafe: battery low ({battery:.0%}), returning to launch", 2))
        events = [dataclasses.replace(e, t=t, link_age=link_age) for e in events]
        self.history.extend(events)
        return events
