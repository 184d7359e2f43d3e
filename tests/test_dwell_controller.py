"""Dwell-time controller (paper 003 sec. III-E) on synthetic histogram streams."""

import math

import numpy as np
import pytest

from planner.dwell_controller import DwellConfig, DwellController
from radseek.topics import FLAG_CRC_ERROR, FLAG_GAP, FLAG_SATURATED, FLAG_STALE_POSE

DT = 0.1  # s, the board's frame period


def run(counts, config=None, flags=None, t0=0.0, times=None):
    """Feed a stream until the controller is done; return the final status."""
    c = DwellController(config)
    st = None
    for k, n in enumerate(counts):
        t = times[k] if times is not None else t0 + (k + 1) * DT
        st = c.update(t, int(n), DT, 0 if flags is None else int(flags[k]))
        if st.done:
            break
    return st


def test_noise_free_stream_converges_at_t_min_with_exact_mean():
    st = run([10] * 400)  # 100 cps exactly: dm/dt = 0 as soon as it is defined
    assert st.done and st.reason == "converged"
    assert st.live_time == pytest.approx(DwellConfig().t_min)
    assert st.mean_rate == pytest.approx(100.0)
    assert st.sigma_rate == pytest.approx(math.sqrt(st.counts) / st.live_time)
    assert st.frames_used == round(st.live_time / DT)


def test_stronger_fields_dwell_longer():
    # 40 seeded dwells each at 20 cps and at 1000 cps with the default rule. The Poisson noise of the
    # running-mean slope is ~sqrt(m / L) / T, so the fixed 2 cps/s term holds a 1000 cps dwell until
    # T ~ sqrt(1000) / 2 ~ 16 s (capped by the Poisson-scaled term near 11-15 s), while 20 cps clears it
    # at T ~ 2 s, i.e. stops at t_min + a little. Observed spreads are ~0.5 s and ~2.5 s, so the mean
    # difference (~7 s expected) has a standard error ~0.4 s; 3 s is > 9 standard errors below it.
    rng = np.random.default_rng(11)
    low = [run(rng.poisson(20 * DT, 400)).live_time for _ in range(40)]
    high = [run(rng.poisson(1000 * DT, 400)).live_time for _ in range(40)]
    assert np.mean(high) - np.mean(low) > 3.0
    cfg = DwellConfig()
    assert min(low) >= cfg.t_min - 1e-9 and max(high) <= cfg.t_max + 1e-9


def test_reported_sigma_matches_poisson_scatter_of_the_mean():
    # fixed 10 s dwells (t_min = t_max) so the stopping rule cannot select: 400 seeded dwells at 200 cps.
    # The sample variance of 400 means has relative standard error sqrt(2 / 399) = 0.071; accept the
    # ratio empirical var / mean reported sigma^2 within 4 of those (0.72 .. 1.28).
    cfg = DwellConfig(t_min=10.0, t_max=10.0)
    rng = np.random.default_rng(5)
    sts = [run(rng.poisson(200 * DT, 100), cfg) for _ in range(400)]
    assert all(s.reason in ("t_max", "converged") and s.live_time == pytest.approx(10.0) for s in sts)
    means = np.array([s.mean_rate for s in sts])
    sig = np.array([s.sigma_rate for s in sts])
    ratio = means.var(ddof=1) / np.mean(sig**2)
    assert 1 - 4 * math.sqrt(2 / 399) < ratio < 1 + 4 * math.sqrt(2 / 399)
    assert np.mean(sig) == pytest.approx(math.sqrt(200 / 10.0), rel=0.02)  # sqrt(lambda / T)


def test_adaptive_stop_keeps_the_mean_unbiased():
    # with the adaptive rule on, z = (m - lambda) / sigma should still be ~N(0, 1): over 300 dwells the
    # fraction with |z| < 1 is 0.683 +- 3 * sqrt(0.683 * 0.317 / 300) = +- 0.081, the mean z 0 +- 3 / sqrt(300).
    rng = np.random.default_rng(8)
    lam = 300.0
    z = np.array([(s.mean_rate - lam) / s.sigma_rate for s in (run(rng.poisson(lam * DT, 400)) for _ in range(300))])
    assert abs(np.mean(np.abs(z) < 1) - 0.683) < 0.081
    assert abs(z.mean()) < 3 / math.sqrt(300)


@pytest.mark.parametrize("bad", [FLAG_STALE_POSE, FLAG_CRC_ERROR, FLAG_SATURATED])
def test_stale_corrupt_and_saturated_frames_are_not_counted(bad):
    counts = [10, 999] * 200  # every other frame is bad and carries garbage counts
    flags = [0, bad] * 200
    st = run(counts, flags=flags)
    assert st.mean_rate == pytest.approx(100.0)
    assert st.frames_rejected == st.frames_used or st.frames_rejected == st.frames_used - 1
    # the dwell clock counts only good frames: sim time elapsed is about twice the live time
    assert st.elapsed == pytest.approx(2 * st.live_time, abs=2 * DT)


def test_gap_pauses_the_timer():
    # 3 s of frames are lost after 2 s: the frame after the gap carries FLAG_GAP
    n = 200
    times = np.r_[np.arange(1, 21) * DT, 2.0 + 3.0 + np.arange(1, n - 19) * DT]
    flags = np.zeros(n, dtype=int)
    flags[20] = FLAG_GAP
    st = run([10] * n, flags=flags, times=times)
    assert st.reason == "converged"
    assert st.live_time == pytest.approx(DwellConfig().t_min)  # the gap did not count towards t_min
    assert st.elapsed == pytest.approx(st.live_time + 3.0)
    assert st.frames_rejected == 0


def test_t_max_caps_a_mean_that_keeps_drifting():
    # the rate ramps up steadily (a source coming into view): dm/dt stays above any threshold
    counts = [int(5 + 5 * k) for k in range(400)]
    st = run(counts)
    assert st.reason == "t_max"
    assert st.live_time == pytest.approx(DwellConfig().t_max)


def test_timeout_when_no_usable_frames_arrive():
    st = run([10] * 1000, flags=[FLAG_STALE_POSE] * 1000)
    assert st.reason == "timeout"
    assert st.frames_used == 0 and math.isnan(st.mean_rate)
    assert st.elapsed == pytest.approx(DwellConfig().t_timeout)


def test_finished_dwell_stays_finished_until_reset():
    c = DwellController()
    st = None
    for k in range(200):
        st = c.update((k + 1) * DT, 10, DT)
    assert st is not None and st.done
    assert c.update(100.0, 10_000, DT) == st
    c.reset()
    fresh = c.update(200.0, 10, DT)
    assert not fresh.done and fresh.frames_used == 1


def test_config_bounds_are_enforced():
    with pytest.raises(ValueError):
        DwellConfig(t_min=10, t_max=5)
    with pytest.raises(ValueError):
        DwellConfig(t_thres=0)
    with pytest.raises(ValueError):
        DwellConfig(t_timeout=1.0)


def test_histogram_messages_feed_the_controller():
    from radseek.topics import Histogram

    c = DwellController()
    counts = [0] * 32
    counts[12], counts[13] = 6, 4  # 10 counts per 0.1 s frame
    st = None
    for k in range(100):
        msg = Histogram(seq=k, board_time=k * DT, t=(k + 1) * DT, duration=DT, counts=counts,
                        flags=FLAG_STALE_POSE if k % 5 == 4 else 0)
        st = c.update_histogram(msg)
        if st.done:
            break
    assert st is not None and st.done and st.mean_rate == pytest.approx(100.0)
    assert st.frames_rejected == st.frames_used // 4
