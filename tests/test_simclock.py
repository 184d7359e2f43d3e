"""The shared simulation clock, over a real zenoh router on loopback.

Nothing here asserts how long anything took on the wall clock: the free-running clock is checked against
wall readings taken around it (an exact bracket, whatever the load), and the follower against the sim
times the owner published. Wall deadlines only bound waiting."""

import time

import pytest

from radseek.simclock import ClockPublisher, FreeRunningClock, ZenohClock
from radseek.zenoh_session import open_session

WAIT_S = 30.0


def _wait_for(cond, what: str, timeout: float = WAIT_S) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)


def test_free_running_clock_scales_wall_time():
    speedup = 20.0
    w_init = time.monotonic()
    clock = FreeRunningClock(speedup=speedup, t0=3.0)
    w0 = time.monotonic()
    s0 = clock.now()
    w1 = time.monotonic()
    assert clock.sleep_until(4.0)  # 1 sim second = 50 ms wall
    w2 = time.monotonic()
    s1 = clock.now()
    w3 = time.monotonic()
    assert s1 >= 4.0  # it does not wake early (it may wake late on a loaded host)
    # sim time elapsed is speedup x wall time elapsed, bracketed by the wall readings around each now()
    assert speedup * (w2 - w1) <= s1 - s0 <= speedup * (w3 - w0)
    assert 3.0 <= s0 <= 3.0 + speedup * (w1 - w_init)  # starts at t0
    assert clock.sleep_until(2.0)  # a time already past returns at once
    with pytest.raises(ValueError):
        FreeRunningClock(speedup=0)


def test_follower_tracks_owner_and_stalls_with_it(router):
    with open_session(connect=router) as owner, open_session(connect=router) as follower:
        clock = ZenohClock(follower, "uav0", max_lead=0.05)
        pub = ClockPublisher(owner, "uav0", speedup=10.0)
        assert not clock.started and clock.now() == 0.0
        # publish t = 0 until the follower hears it (the subscription is matched), instead of sleeping
        deadline = time.monotonic() + WAIT_S
        while not clock.wait_started(0.05):
            assert time.monotonic() < deadline, "the follower never heard sim/clock"
            pub.publish(0.0)
        for k in range(1, 20):
            pub.publish(k * 0.1)
        # the owner stopped at 1.9 s: the follower gets there ...
        _wait_for(lambda: clock.now() >= 1.9, "the follower to reach the owner's last time 1.9 s")
        # ... and, however long it waits (here >= 0.2 s wall = 2 s sim of uncapped lead), leads by at most max_lead
        time.sleep(0.2)
        assert 1.9 <= clock.now() <= 1.95 + 1e-9
        assert clock.speedup == 10.0
        assert not clock.sleep_until(5.0, timeout_wall_s=0.2)
        assert 1.9 <= clock.now() <= 1.95 + 1e-9
