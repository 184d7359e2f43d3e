"""The shared simulation clock, over a real zenoh router on loopback."""

import time

import pytest

from radseek.simclock import ClockPublisher, FreeRunningClock, ZenohClock
from radseek.zenoh_session import open_session


def test_free_running_clock_scales_wall_time():
    clock = FreeRunningClock(speedup=20.0)
    assert clock.sleep_until(1.0)  # 1 sim second = 50 ms wall
    assert 1.0 <= clock.now() < 1.6
    with pytest.raises(ValueError):
        FreeRunningClock(speedup=0)


def test_follower_tracks_owner_and_stalls_with_it(router):
    with open_session(connect=router) as owner, open_session(connect=router) as follower:
        clock = ZenohClock(follower, "uav0", max_lead=0.05)
        pub = ClockPublisher(owner, "uav0", speedup=10.0)
        time.sleep(0.3)
        for k in range(20):
            pub.publish(k * 0.1)
            time.sleep(0.01)
        assert clock.wait_started(2.0)
        time.sleep(0.2)
        # the owner stopped at 1.9 s: the follower may lead by at most max_lead
        assert 1.9 <= clock.now() <= 1.95 + 1e-9
        assert clock.speedup == 10.0
        assert not clock.sleep_until(5.0, timeout_wall_s=0.2)
