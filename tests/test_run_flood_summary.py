"""Issue 34 (a): a whole `radseek run` (one vehicle) flooded and forged by a compromised board, checked through its
summary.json.

The attacker holds the run's own detector credential (``detector@uav0`` from OUT/zenoh/credentials, as a second
process on the board would), so the router lets it put every ``detector/*`` key. Once the real detector has sent
its first histogram it floods ``detector/histogram`` and ``detector/status`` with forged payloads at 100 times
their contract rate (``topics.EXPECTED_RATES`` at the run's speed-up), and replays each real histogram a second
later with the real detector's own zenoh id and sequence number (``source_info``) and forged counts. The run keeps its
result, frame for frame the flight an unattacked run flies (``launch.offline.fly_offline``, as
tests/test_one_world.py compares: lockstep makes the flight independent of timing), and summary.json names per
key and publisher what was dropped: the flooder's samples as a flood or as another publisher's, the copies as a
forged sequence; stderr says it in one line per key and publisher.
"""

from __future__ import annotations

import json
import queue
import re
import subprocess
import sys
import threading
import time

import pytest
import zenoh

from detector_fw_sim.scene import load_scene
from launch.offline import fly_offline
from launch.ports import ZENOH_BASE
from mission.key_accounts import UNKNOWN_PUBLISHER
from mission.recorder import flagged_rows
from mission.search import SearchConfig
from radseek import topics
from radseek.zenoh_auth import find_user
from radseek.zenoh_session import open_session
from radseek_io.dataset import read_dataset
from tests.support.run_credentials import wait_for_credentials
from tests.support.team_frames import assert_frames_csv

INSTANCE = 6  # fixed ports (PX4's -i 6), held machine-wide by the exclusive mark
SPEEDUP = 5.0
SEED = 3
MAX_DWELLS = 16  # radseek run's default; seed 3 finds the source in 5
FLOOD_X = 100.0  # times the contract rate
COPY_AFTER_S = 10.0  # wall s after the original a copy is sent (1 s, then 5 s: loaded clean-clone runs stalled past it)
RUN_TIMEOUT_S = 900
HIST, STATUS = topics.key(topics.HISTOGRAM, "uav0"), topics.key(topics.DETECTOR_STATUS, "uav0")
FORGED = topics.Histogram(seq=10**7, board_time=1.0, t=1.0, duration=0.1, counts=[65535] * 32).to_bytes()
#: a status that, taken, would tell the mission every frame up to 1e6 s is handled
FORGED_STATUS = topics.DetectorStatus(t=1e6, frames=10**7, stale_frames=0, crc_errors=0,
                                      last_histogram_t=1e6).to_bytes()

# its fixed instance is its own; the lock it takes is the default ports' too, so that it never runs beside the
# side-by-side stacks (tests/support/side_by_side_runs.py): its 100x flood starved them (their missions heard no
# histogram in 60 s) and itself (the board's copies overtook the originals) on a clean-clone make test
pytestmark = [pytest.mark.slow, pytest.mark.io, pytest.mark.exclusive("default-ports-7447-14540"),
              pytest.mark.timeout(RUN_TIMEOUT_S + 300)]


def _hurried_frames(out) -> int:
    """The frames the run's detector made without the true pose at their end (its stop line in logs/detector.log):
    each may differ from the unhurried flight's by a count or so."""
    line = (out / "logs" / "detector.log").read_text()
    return int(re.search(r"(\d+) made without the true pose at their end", line).group(1))


def _rate(topic: str) -> float:
    """The contract's samples per wall second of ``topic`` at the run's speed-up."""
    r = topics.EXPECTED_RATES[topic]
    return r.per_sim_s * SPEEDUP + r.per_wall_s


class Board:
    """The compromised board: one session as ``detector@uav0``, flooding and copying until ``stop``."""

    def __init__(self, session: zenoh.Session):
        # BLOCK asked, but the router rewrites every radseek put to DROP (radseek.zenoh_qos): counts below are bounds
        block = zenoh.CongestionControl.BLOCK
        self.stop = threading.Event()
        self.first = threading.Event()
        #: each real histogram's source_info, with the wall time it was heard
        self.heard: queue.Queue[tuple[float, zenoh.SourceInfo]] = queue.Queue()
        self.honest: str | None = None  # the real detector's publisher id
        self.copies = 0
        self.sent = {HIST: 0, STATUS: 0}
        # the histograms stamped with the flooder's own id (as radseek's publishers stamp theirs), the statuses bare
        self.pubs = {HIST: topics.StampedPublisher(session.declare_publisher(HIST, congestion_control=block)),
                     STATUS: session.declare_publisher(STATUS, congestion_control=block)}
        self.copier = session.declare_publisher(HIST, congestion_control=block)
        self.ids = {HIST: f"{self.pubs[HIST].id.zid}/{self.pubs[HIST].id.eid}", STATUS: UNKNOWN_PUBLISHER}
        self.spy = session.declare_subscriber(HIST, self._heard)

    def _heard(self, sample: zenoh.Sample) -> None:
        info = sample.source_info
        if info is None or str(info.source_id.zid) == str(self.copier.id.zid) or \
                sample.payload.to_bytes() == FORGED:
            return  # ours (a session hears its own puts; the copies carry the real id)
        self.honest = self.honest or f"{info.source_id.zid}/{info.source_id.eid}"
        self.heard.put((time.monotonic(), info))
        self.first.set()

    def copy(self) -> None:
        """Each real histogram replayed COPY_AFTER_S after it was heard, with the real detector's id and sequence
        number and forged counts. (A copy sent at once can reach the mission first: a router passes a sample to
        its subscribers one after the other, so under load the forger may hear it, and its copy be routed, before
        the mission's turn comes. That copy is taken and the original dropped: mission/key_accounts.py says so;
        only the router's authentication keeps such a forger out.)"""
        while not self.stop.is_set():
            try:
                heard_at, info = self.heard.get(timeout=0.1)
            except queue.Empty:
                continue
            time.sleep(max(0.0, heard_at + COPY_AFTER_S - time.monotonic()))
            self.copier.put(FORGED, source_info=zenoh.SourceInfo(info.source_id, info.source_sn))
            self.copies += 1

    def flood(self) -> None:
        """Forged histograms and statuses at FLOOD_X x their contract rate, paced in 10 ms batches."""
        payload = {HIST: FORGED, STATUS: FORGED_STATUS}
        t0 = time.monotonic()
        while not self.stop.is_set():
            elapsed = time.monotonic() - t0
            for key, data in payload.items():
                target = FLOOD_X * _rate(topics.topic_of(key)) * elapsed
                while self.sent[key] < target and not self.stop.is_set():
                    self.pubs[key].put(data)
                    self.sent[key] += 1
            time.sleep(0.01)


def test_a_compromised_board_flooding_and_forging_a_run_is_named_in_its_summary_and_changes_nothing(tmp_path):
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "radseek_cli", "run", "default", "--out", str(out), "--quiet", "--instance",
           str(INSTANCE), "--speedup", str(SPEEDUP), "--seed", str(SEED), "--max-dwells", str(MAX_DWELLS),
           "--no-mcap", "--timeout", str(RUN_TIMEOUT_S)]
    run = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    board: Board | None = None
    threads: list[threading.Thread] = []
    session = None
    try:
        detector = find_user(wait_for_credentials(out, run), "detector", "uav0")
        session = open_session(connect=f"tcp/127.0.0.1:{ZENOH_BASE + INSTANCE}", user=detector,
                               wait_for_router_s=120)
        board = Board(session)
        assert board.first.wait(300), "the real detector never sent a histogram"
        threads = [threading.Thread(target=board.flood, daemon=True), threading.Thread(target=board.copy, daemon=True)]
        for t in threads:
            t.start()
        _, stderr = run.communicate(timeout=RUN_TIMEOUT_S + 60)
    finally:
        if board is not None:
            board.stop.set()
        for t in threads:
            t.join(10)
        if session is not None:
            session.close()
        if run.poll() is None:
            run.kill()
            run.wait()
    assert run.returncode in (0, 3), stderr[-3000:]  # 3: searched to the end of the dwell budget
    assert "Traceback" not in (out / "logs" / "mission.log").read_text()
    summary = json.loads((out / "summary.json").read_text())
    mission = json.loads((out / "dataset" / "mission_summary.json").read_text())
    assert summary["samples"] == mission["samples"]
    ds = read_dataset(out / "dataset")  # readable: frames.csv in time order, whatever came in
    assert (ds.frames.counts < 65535).all()  # no forged histogram was recorded as a measurement
    hurried = _hurried_frames(out)
    if mission["frames_lost"] == 0 and hurried == 0:
        # the flight an unattacked run flies, frame for frame: nothing forged was recorded, nothing real lost
        config = SearchConfig(max_dwells=MAX_DWELLS, max_search_dwells=MAX_DWELLS)
        r = fly_offline(load_scene("default"), config, seed=SEED)
        for key in ("reason", "dwell_points", "mission_time_s", "frames_recorded", "frames_lost"):
            assert r.summary[key] == mission[key], key
        assert r.error_m == pytest.approx(summary["error_m"], abs=1e-9)
        rows = assert_frames_csv(out / "dataset" / "frames.csv", r.dataset.frames)
        assert [int(row["dwell"]) for row in rows] == [int(d) for d in r.dataset.frames.dwell]
    else:
        # a loaded machine: the router dropped real histograms in the flood (zenoh's DROP congestion control), or
        # the detector drew a frame without waiting out its true pose (LOCKSTEP_TRUTH_WAIT_S), so the flight may
        # differ from an unattacked one; a forged copy that came in a lost frame's place is at most flagged
        # (mission/recorder.py), and the run still ends with its report
        assert mission["frames_received"] == mission["frames_recorded"] + flagged_rows(out / "dataset")
        assert flagged_rows(out / "dataset") <= mission["frames_lost"]

    honest = board.honest
    hist = summary["samples"][HIST]
    assert hist["accepted"] == mission["frames_received"] and hist["invalid"] == 0
    assert set(hist["dropped_from"]) == {honest, board.ids[HIST]}, hist  # the copies carry the real detector's id
    flooder = hist["dropped_from"][board.ids[HIST]]
    # the flooder: each of its samples heard dropped, over its rate or as a second publisher (sent before
    # the mission subscribed or after it stopped are not heard)
    assert flooder["flood"] > 0 and flooder["foreign"] > 0 and flooder["sequence"] == flooder["invalid"] == 0
    assert flooder["flood"] + flooder["foreign"] <= board.sent[HIST]
    copied = hist["dropped_from"][honest]
    assert copied == {"flood": 0, "foreign": 0, "sequence": copied["sequence"], "invalid": 0}, copied
    # the copies heard while it listened: all but those of the last COPY_AFTER_S wall seconds' originals (at most
    # 10 Hz x SPEEDUP of them a wall second: a loaded machine flies slower, and the mission hears more)
    assert 0.9 * (hist["accepted"] - COPY_AFTER_S * 10 * SPEEDUP) <= copied["sequence"] <= board.copies
    status = summary["samples"][STATUS]["dropped_from"][board.ids[STATUS]]
    assert status["flood"] > 0 and status["flood"] + status["foreign"] <= board.sent[STATUS]
    # one line per key and publisher on stderr, and in summary.json's warnings
    for key, publisher in ((HIST, board.ids[HIST]), (HIST, honest), (STATUS, board.ids[STATUS])):
        lines = [w for w in summary["warnings"] if w.startswith("dropped ") and f" on {key} from {publisher} " in w]
        assert len(lines) == 1, summary["warnings"]
        assert f"radseek run: warning: {lines[0]}" in stderr.splitlines()
