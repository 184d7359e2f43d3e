"""Issue 34 item 2: the mission survives a flood of its own keys and names the key that was flooded or forged.

The bucket arithmetic is checked on an analytic case (a clock the test steps); the mission's own histogram
subscriber (``mission.mission_process._Stream``) is checked against a real `radseek detector` at 10 Hz of sim
time over a real router, while a second session floods the detector key with 5,000 histograms.
"""

from __future__ import annotations

import asyncio
import logging
import re
import subprocess
import sys
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

from mission import key_accounts
from mission.key_accounts import KeyAccounts
from radseek import topics

KEY = topics.key(topics.HISTOGRAM, "uav0")
HIST = topics.Histogram(seq=1, board_time=1.0, t=1.0, duration=0.1, counts=[1] * 32)


class _Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def _sample(key: str, payload: bytes, zid: str | None) -> SimpleNamespace:
    """What a zenoh callback gets: key, payload and (for a stamped publisher) its id."""
    info = None if zid is None else SimpleNamespace(source_id=SimpleNamespace(zid=zid, eid=1))
    return SimpleNamespace(key_expr=key, payload=SimpleNamespace(to_bytes=lambda: payload), source_info=info)


def test_a_publisher_over_its_rate_is_dropped_as_a_flood_and_named_once_per_period(caplog):
    clock = _Clock()
    acc = KeyAccounts(logging.getLogger("t.flood"), speedup=2.0, clock=clock)
    limit = key_accounts.FLOOD_FACTOR * 10.0 * 2.0  # histograms: 10 per sim s, at x2 speed-up
    burst = max(key_accounts.MIN_BURST, limit * key_accounts.BURST_WALL_S)
    caplog.set_level(logging.WARNING, "t.flood")
    taken = sum(acc.decode(topics.Histogram, _sample(KEY, HIST.to_bytes(), "board")) is not None for _ in range(5000))
    assert taken == burst  # the burst, then nothing at a frozen clock
    clock.now = 1.0  # one wall second refills one second at the limit
    taken = sum(acc.decode(topics.Histogram, _sample(KEY, HIST.to_bytes(), "board")) is not None for _ in range(5000))
    assert taken == limit
    flood = 10000 - burst - limit
    assert acc.counts()[KEY] == {"accepted": burst + limit, "flood": flood, "foreign": 0, "sequence": 0, "invalid": 0,
                                 "dropped_from": {"board/1": {"flood": flood, "foreign": 0, "sequence": 0,
                                                              "invalid": 0}}}
    floods = [r.getMessage() for r in caplog.records if r.getMessage().startswith("flood on")]
    assert len(floods) == 1, floods  # at most one line per WARN_EVERY_WALL_S
    assert KEY in floods[0] and "board/1" in floods[0] and "20/s expected" in floods[0]
    clock.now += key_accounts.WARN_EVERY_WALL_S
    for _ in range(int(limit * key_accounts.WARN_EVERY_WALL_S) + 1):
        acc.admit(_sample(KEY, b"", "board"))
    floods = [r.getMessage() for r in caplog.records if r.getMessage().startswith("flood on")]
    assert len(floods) == 2, floods


def test_without_a_speedup_the_accounts_follow_the_vehicles_clock():
    """A mission started by hand without --speedup beside a vehicle at --speedup 10 took the detector's 100
    histograms per wall second for a flood (limit 5 x 10/s) and dropped half of them. Following the clock measured
    from the poses, an honest board at x10 loses nothing after the first window; a hold (lockstep) never lowers
    the rate followed, and a fixed --speedup is kept whatever the clock does."""
    clock = _Clock()
    window = key_accounts.SPEEDUP_WINDOW_WALL_S

    def board_at_x10(acc: KeyAccounts) -> tuple[int, int]:
        """10 windows of wall time, a histogram every 0.01 s: (taken, dropped) after the first two windows."""
        taken = dropped = 0
        for step in range(int(10 * window / 0.01)):
            clock.now = step * 0.01
            if step % 5 == 0:  # a pose every 0.05 wall s: 20 Hz of sim time at x10
                acc.observe_sim_time(10.0 * clock.now)
            ok = acc.admit(_sample(KEY, b"", "board"))
            if clock.now >= 2 * window:
                taken, dropped = taken + ok, dropped + (not ok)
        return taken, dropped

    taken, dropped = board_at_x10(KeyAccounts(logging.getLogger("t.x1"), speedup=1.0, clock=clock))
    assert dropped > 0.4 * (taken + dropped)  # the fault as it was: half the honest board's frames lost
    acc = KeyAccounts(logging.getLogger("t.follow"), speedup=None, clock=clock)
    assert acc.speedup == 1.0 and acc.follows_clock
    taken, dropped = board_at_x10(acc)
    assert acc.speedup == pytest.approx(10.0, rel=0.05)
    assert dropped == 0 and taken > 0
    for _ in range(5):  # lockstep holds sim time for 5 wall s
        clock.now += window
        acc.observe_sim_time(10.0 * 10 * window)
    assert acc.speedup == pytest.approx(10.0, rel=0.05)

    fixed = KeyAccounts(logging.getLogger("t.fixed"), speedup=2.0, clock=clock)
    for k in range(5):
        clock.now += window
        fixed.observe_sim_time(100.0 * k)
    assert fixed.speedup == 2.0 and not fixed.follows_clock


def test_a_second_publisher_is_dropped_as_forged_until_the_first_falls_silent(caplog):
    clock = _Clock()
    acc = KeyAccounts(logging.getLogger("t.forge"), clock=clock)
    caplog.set_level(logging.WARNING, "t.forge")
    assert acc.decode(topics.Histogram, _sample(KEY, HIST.to_bytes(), "board")) is not None
    assert acc.decode(topics.Histogram, _sample(KEY, HIST.to_bytes(), None)) is None
    assert acc.decode(topics.Histogram, _sample(KEY, b"{junk", "board")) is None
    counts = acc.counts()[KEY]
    assert {k: counts[k] for k in key_accounts.DROP_KINDS} == {"flood": 0, "foreign": 1, "sequence": 0, "invalid": 1}
    assert counts["accepted"] == 1
    assert counts["dropped_from"] == {"board/1": {"flood": 0, "foreign": 0, "sequence": 0, "invalid": 1},
                                      "unknown publisher": {"flood": 0, "foreign": 1, "sequence": 0, "invalid": 0}}
    text = caplog.text
    assert f"second publisher on {KEY}: unknown publisher" in text and "while board/1 publishes it" in text
    assert f"invalid sample #1 on {KEY} from board/1" in text
    clock.now = key_accounts.OWNER_SILENT_WALL_S + 0.1  # the board fell silent: a restarted board takes the key
    # ... but not the publisher refused while the board spoke (a flooder waiting out a lockstep pause)
    assert acc.decode(topics.Histogram, _sample(KEY, HIST.to_bytes(), None)) is None
    assert acc.decode(topics.Histogram, _sample(KEY, HIST.to_bytes(), "board2")) is not None
    assert acc.decode(topics.Histogram, _sample(KEY, HIST.to_bytes(), "board")) is None


def test_an_honest_run_reports_no_publisher_for_its_keys():
    """Nothing dropped on a key: no ``dropped_from`` (the summary of an honest run names nobody)."""
    acc = KeyAccounts(logging.getLogger("t.honest"), clock=_Clock())
    for _ in range(5):
        assert acc.decode(topics.Histogram, _sample(KEY, HIST.to_bytes(), "board")) is not None
    assert acc.counts() == {KEY: {"accepted": 5, "flood": 0, "foreign": 0, "sequence": 0, "invalid": 0}}


def _forge_copies(endpoint: str, n_honest: int, got: list) -> str:
    """Honest publisher and forger on real sessions: a stamped publisher puts ``n_honest`` histograms; once
    they are in ``got``, a forger that heard them puts, with the honest publisher's own zenoh id, a copy of each
    sequence number (forged counts) and then numbers going back from the last. Returns the honest id."""
    import zenoh

    from radseek.zenoh_session import open_session

    heard: list = []
    with open_session(connect=endpoint) as honest_s, open_session(connect=endpoint) as forger_s:
        forged = topics.Histogram(seq=10**7, board_time=1.0, t=1.0, duration=0.1, counts=[65535] * 32).to_bytes()
        spy = forger_s.declare_subscriber(  # a session hears its own puts too: not its forged ones
            KEY, lambda s: s.payload.to_bytes() != forged and heard.append(s.source_info))
        time.sleep(0.5)  # no history in zenoh: the subscribers join before the first put
        honest = topics.declare_publisher(honest_s, topics.HISTOGRAM, "uav0")
        for i in range(n_honest):
            honest.put(topics.Histogram(seq=i, board_time=0.1 * i, t=0.1 * i, duration=0.1, counts=[1] * 32)
                       .to_bytes())
        deadline = time.monotonic() + 30
        while (len(heard) < n_honest or len(got) < n_honest) and time.monotonic() < deadline:
            time.sleep(0.05)
        forger = forger_s.declare_publisher(KEY)
        heard = heard[:n_honest]
        last = heard[-1].source_sn
        for info in heard:  # the very source_info each honest sample carried: same id, same number
            forger.put(forged, source_info=zenoh.SourceInfo(info.source_id, info.source_sn))
        for sn in range(last - 1, 0, -1):  # its own numbers, going back from the last taken
            forger.put(forged, source_info=zenoh.SourceInfo(heard[0].source_id, sn))
        time.sleep(1.0)  # the router passes the last ones on before the sessions close
        spy.undeclare()
        return f"{honest.id.zid}/{honest.id.eid}"


@pytest.mark.io
@pytest.mark.timeout(120)
def test_a_copy_of_the_detectors_id_with_a_taken_sequence_number_is_dropped_as_forged(router, caplog):
    """Issue 34 (b): a forger that copies the detector's zenoh ``source_info`` passes the rate limit and the
    one-publisher rule; its repeated and backward sequence numbers are dropped and named "forged (sequence)"."""
    from radseek.zenoh_session import open_session

    n = 20
    caplog.set_level(logging.WARNING, "t.seq")
    accounts = KeyAccounts(logging.getLogger("t.seq"), speedup=1.0)
    got: list = []
    with open_session(connect=router) as session:
        sub = session.declare_subscriber(
            KEY, lambda s: (h := accounts.decode(topics.Histogram, s)) is not None and got.append(h))
        time.sleep(0.5)
        publisher = _forge_copies(router, n, got)  # the honest publisher's id, as the forger copied it
        deadline = time.monotonic() + 30
        forged = n + (n - 1)  # a copy of each number taken, then n-1 .. 1
        while accounts.counts()[KEY]["sequence"] < forged and time.monotonic() < deadline:
            time.sleep(0.05)
        sub.undeclare()
    assert [h.seq for h in got] == list(range(n)) and all(h.counts == [1] * 32 for h in got)
    counts = accounts.counts()[KEY]
    assert counts["accepted"] == n and counts["sequence"] == forged, counts
    assert counts["flood"] == counts["foreign"] == counts["invalid"] == 0, counts
    assert counts["dropped_from"] == {publisher: {"flood": 0, "foreign": 0, "sequence": forged, "invalid": 0}}
    lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith("forged (sequence)")]
    assert len(lines) == 1, lines  # named once per WARN_EVERY_WALL_S, not per sample
    assert lines[0].startswith(f"forged (sequence) on {KEY} from {publisher}: sequence number 1 after {n} ")


def _flood(endpoint: str, n: int, sent: list[int]) -> None:
    """A second session puts ``n`` well-formed histograms (seq from 10**7) on the detector key at once."""
    import zenoh

    from radseek.zenoh_session import open_session

    with open_session(connect=endpoint) as s:
        pub = s.declare_publisher(KEY, congestion_control=zenoh.CongestionControl.BLOCK)
        for i in range(n):
            pub.put(topics.Histogram(seq=10**7 + i, board_time=1.0, t=1.0, duration=0.1, counts=[7] * 32).to_bytes())
            sent[0] += 1
        time.sleep(1.0)  # let the router pass the last ones on before the session closes


async def _fly_under_flood(endpoint: str, out, accounts: KeyAccounts, n_flood: int):
    """The mission's histogram subscriber on a real session: take the detector's frames as the flight does (one
    queue), start the flood after 20 of them, stop 30 frames after it ends. Returns the frames taken, the stream
    and how many flood samples were put."""
    from mission.mission_process import _Stream
    from mission.recorder import FlightRecorder
    from radseek.dataset import Scenario
    from radseek.zenoh_session import open_session

    scenario = Scenario(channel_edges_keV=np.linspace(40, 1640, 33), background_cps=30.0, source_z=0.0,
                        bounds_min=np.zeros(3), bounds_max=np.array([10.0, 10.0, 3.0]))
    recorder = FlightRecorder(out, scenario)
    stream = _Stream(asyncio.get_running_loop(), recorder, accounts)
    taken: list[topics.Histogram] = []
    sent = [0]
    flood = threading.Thread(target=_flood, args=(endpoint, n_flood, sent), daemon=True)
    with open_session(connect=endpoint) as session:
        sub = session.declare_subscriber(KEY, stream.on_histogram)
        try:
            after = None
            while after is None or len(taken) < after + 30:
                taken.append(await asyncio.wait_for(stream.queue.get(), 60))
                if len(taken) == 20:
                    flood.start()
                if after is None and flood.ident is not None and not flood.is_alive():
                    after = len(taken)
        finally:
            sub.undeclare()
            flood.join(30)
            # a callback already running when undeclare returned may still be counting its sample: let the count
            # settle (unchanged over two polls) before the last flush, so what was accepted is what was recorded
            last, still = -1, 0
            for _ in range(100):
                now = accounts.counts().get(KEY, {}).get("accepted", 0)
                still = still + 1 if now == last else 0
                if still >= 2:
                    break
                last = now
                await asyncio.sleep(0.05)
            stream.flush()
            recorder.close()
    return taken, stream, sent[0]


@pytest.mark.io
@pytest.mark.timeout(300)
def test_a_flood_on_the_detector_key_is_dropped_named_and_counted_while_the_10hz_frames_go_on(router, tmp_path,
                                                                                                caplog):
    speedup = 5.0
    det = subprocess.Popen([sys.executable, "-m", "radseek_cli", "detector", "--connect", router, "--clock", "own",
                            "--speedup", str(speedup), "--pose", "1,1,1.5,0"],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    caplog.set_level(logging.WARNING, "t.mission")
    accounts = KeyAccounts(logging.getLogger("t.mission"), speedup)
    try:
        taken, stream, sent = asyncio.run(_fly_under_flood(router, tmp_path / "flight", accounts, 5000))
    finally:
        det.terminate()
        det.wait(30)
    assert sent == 5000
    counts = accounts.counts()[KEY]
    # every flood sample heard was dropped (over the rate, or a second publisher on the key), none recorded
    assert counts["flood"] + counts["foreign"] == 5000, counts
    assert counts["flood"] > 0 and counts["invalid"] == counts["sequence"] == 0, counts
    assert all(h.seq < 10**7 for h in taken)
    # the detector's own frames, every one, 10 per sim second: consecutive sequence numbers 0.1 s of sim time apart
    seqs = [h.seq for h in taken]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), seqs
    assert np.allclose(np.diff([h.t for h in taken]), 0.1, atol=1e-6)
    assert counts["accepted"] == stream.recorder.received >= len(taken)
    # bounded: the queue never held more than its cap
    from mission.mission_process import QUEUE_CAP

    assert stream.queue_high <= QUEUE_CAP and stream.queue_dropped == 0
    lines = [r.getMessage() for r in caplog.records]
    flood = [m for m in lines if m.startswith(f"flood on {KEY} from ")]
    assert flood, lines[:20]
    assert re.search(r": \d+ samples(/s| at once) observed, 50/s expected \(x5 speed-up\)", flood[0]), flood[0]
    assert any(m.startswith(f"second publisher on {KEY}: unknown publisher") for m in lines), lines[:20]
    assert len(flood) * 10 < counts["flood"]  # named at most every WARN_EVERY_WALL_S, not once per sample
