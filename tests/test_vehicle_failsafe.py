"""Failsafes: the pure policy, then link loss and low battery on a running vehicle over UDP."""

import math
import time

import pytest
from pymavlink.dialects.v20 import common as M

from vehicle_sim.battery import BatteryParams
from vehicle_sim.failsafe import Action, Failsafe, FailsafeParams
from vehicle_sim.harness import Gcs, VehicleThread, free_udp_port, thread_config
from vehicle_sim.navigator import Mode, px4_custom_mode


def test_policy_link_loss_hold_then_rtl_and_recovery():
    fs = Failsafe(FailsafeParams(link_loss_timeout_s=2.0, link_loss_hold_s=10.0), low=0.25, critical=0.1)
    assert fs.update(0.0, link_seen=False, link_age=100.0, battery=1.0, in_air=True) == []  # no GCS yet
    assert fs.update(1.0, True, 1.0, 1.0, True) == []
    (ev,) = fs.update(2.0, True, 2.5, 1.0, True)
    assert ev.action is Action.HOLD and "link lost" in ev.text
    assert fs.update(11.9, True, 12.0, 1.0, True) == []
    (ev,) = fs.update(12.0, True, 12.1, 1.0, True)
    assert ev.action is Action.RTL
    assert fs.update(13.0, True, 13.0, 1.0, True) == []  # fires once
    (ev,) = fs.update(14.0, True, 0.1, 1.0, True)
    assert ev.action is Action.NONE and "regained" in ev.text


def test_policy_battery_low_then_critical_once_each():
    fs = Failsafe(FailsafeParams(), low=0.25, critical=0.1)
    assert fs.update(0, True, 0, 0.3, True) == []
    assert [e.action for e in fs.update(1, True, 0, 0.24, True)] == [Action.RTL]
    assert fs.update(2, True, 0, 0.2, True) == []
    assert [e.action for e in fs.update(3, True, 0, 0.09, True)] == [Action.LAND]
    assert fs.update(4, True, 0, 0.05, True) == []
    assert Failsafe(FailsafeParams(enabled=False), 0.25, 0.1).update(0, True, 99, 0.0, True) == []


# Generous wall deadlines for waiting only: every timing assertion below is on sim time (the failsafe's
# event stamps), never on how long something took on the wall clock, so a loaded host only slows it down.
WAIT_S = 60.0


def _takeoff(gcs):
    gcs.wait_vehicle(WAIT_S)
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, timeout=WAIT_S) == M.MAV_RESULT_ACCEPTED
    assert gcs.command(M.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 7, timeout=WAIT_S) == M.MAV_RESULT_ACCEPTED


def _texts(gcs, want, timeout=WAIT_S, keepalive=False):
    """Collect STATUSTEXTs until one contains ``want``; heartbeats keep the link alive if asked."""
    deadline = time.monotonic() + timeout
    texts = []
    while time.monotonic() < deadline:
        if keepalive:
            gcs.heartbeat()
        for m in gcs.poll(0.05):
            if m.get_type() == "STATUSTEXT":
                texts.append(m.text)
                if want in m.text:
                    return texts
    raise AssertionError(f"no {want!r} in {texts}")


@pytest.mark.io
def test_link_loss_holds_then_returns_to_launch():
    gcs_port = free_udp_port()
    # the link-loss timeout is on the link's (wall) clock, the hold before RTL in sim seconds
    timeout_s, hold_s = 1.5, 4.0
    cfg = thread_config(free_udp_port(), gcs_port, speedup=10.0,
                        failsafe=FailsafeParams(link_loss_timeout_s=timeout_s, link_loss_hold_s=hold_s))
    with VehicleThread(cfg) as vehicle, Gcs(gcs_port) as gcs:
        _takeoff(gcs)
        texts = _texts(gcs, "Takeoff complete", keepalive=True)
        assert vehicle.failsafe.history == []  # the heartbeats kept the link up all through the takeoff
        # the GCS goes silent: hold, then (hold_s sim seconds later) return to launch, and land at home
        texts += _texts(gcs, "link lost")
        gcs.recv("HEARTBEAT", lambda m: m.custom_mode == px4_custom_mode(Mode.HOLD) and
                 m.system_status == M.MAV_STATE_CRITICAL, timeout=WAIT_S)
        texts += _texts(gcs, "returning to launch")
        texts += _texts(gcs, "Landing detected")
        assert vehicle.nav.landed and abs(vehicle.nav.pos[0]) < 0.3 and abs(vehicle.nav.pos[1]) < 0.3
    assert not any("regained" in t for t in texts), texts
    # exactly two transitions, stamped in sim time by the failsafe itself
    hold, rtl = vehicle.failsafe.history
    assert hold.action is Action.HOLD and rtl.action is Action.RTL
    assert hold.link_age > timeout_s  # fired only once the link clock passed the timeout
    # RTL at the first step at least hold_s sim seconds after the hold, however slow the host ran
    assert hold_s <= rtl.t - hold.t <= hold_s + cfg.dt + 1e-9, (hold, rtl)


@pytest.mark.io
def test_low_battery_returns_to_launch():
    gcs_port = free_udp_port()
    cfg = thread_config(free_udp_port(), gcs_port, speedup=20.0,
                        battery=BatteryParams(hover_endurance_s=40.0, low_threshold=0.6, critical_threshold=0.05))
    with VehicleThread(cfg) as vehicle, Gcs(gcs_port) as gcs:
        _takeoff(gcs)
        texts = _texts(gcs, "battery low", keepalive=True)
        gcs.recv("SYS_STATUS", lambda m: m.battery_remaining <= 60, timeout=WAIT_S)
        texts += _texts(gcs, "Landing detected", keepalive=True)
        assert vehicle.nav.landed and abs(vehicle.nav.pos[0]) < 0.3 and abs(vehicle.nav.pos[1]) < 0.3
    assert any("Failsafe" in t for t in texts)
    (low,) = vehicle.failsafe.history  # one RTL for the low battery; the critical level never came
    assert low.action is Action.RTL and "battery low" in low.text
    # the drain: ~40 % of a 40 s hover endurance is about 16 sim s (sim time of the event, not of our look)
    assert 12.0 < low.t < 25.0, low.t
