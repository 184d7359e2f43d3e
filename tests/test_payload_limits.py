"""Zenoh payloads are checked against their schema AND the board's physical limits (issue 12).

A schema-valid histogram with counts of 1e20 cannot have come from the board (u16 per channel); it
must be logged and dropped with a counter, never recorded (it used to be written to frames.csv, crash
the report and make every reader refuse the flight). Deeply nested JSON is a PayloadError, not a
RecursionError traceback in the logs.

The process test runs a real `radseek mission` (its recorder is live while it waits for an autopilot)
over a real zenoh router on loopback and publishes into it."""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from radseek import topics
from radseek.zenoh_session import open_session
from radseek_io.dataset import read_dataset, write_json
from tests.test_detector_stream import Proc
from vehicle_sim.harness import free_udp_port

WAIT_S = 120.0
NESTED = b"[" * 100_000 + b"]" * 100_000


def _hist(seq: int, counts: list[int] | None = None, **kw) -> dict:
    t = 0.1 * (seq + 1)
    return {"seq": seq, "board_time": t, "t": t, "duration": 0.1, "counts": counts or [3] * 32, "flags": 0, **kw}


def test_histogram_limits_are_the_boards():
    ok = topics.Histogram.from_bytes(json.dumps(_hist(4, [65535] * 32)).encode())
    assert ok.total == 32 * 65535
    bad = {
        "counts": (_hist(1, [10**20] + [0] * 31), "counts[0] must be an integer in [0, 65535]"),
        "count 65536": (_hist(1, [0] * 31 + [65536]), "counts[31]"),
        "seq u32": (_hist(2**32, t=1.0, board_time=1.0), "'seq'"),
        "flags u8": (_hist(1, flags=256), "'flags'"),
        "duration": (_hist(1, duration=1e12), "'duration'"),
        "negative t": (_hist(1, t=-5.0), "'t'"),
        "huge t": (_hist(1, t=1e300), "'t'"),
        "live_time": (_hist(1, live_time=5.0), "'live_time'"),
        "live_time type": (_hist(1, live_time="x"), "'live_time'"),
        "wall_time nan": (_hist(1, wall_time=float("nan")), "'wall_time'"),
    }
    for payload, msg in bad.values():
        with pytest.raises(topics.PayloadError, match=re.escape(msg)):
            topics.Histogram.from_bytes(json.dumps(payload).encode())


@pytest.mark.parametrize("cls", list(topics.PAYLOADS.values()), ids=list(topics.PAYLOADS))
def test_deep_nesting_and_huge_numbers_are_payload_errors(cls):
    for raw in (NESTED, b'{"t": ' + NESTED + b"}", b'{"t": ' + b"9" * 5000 + b"}", b'{"t": 1' + b"0" * 400 + b"}"):
        with pytest.raises(topics.PayloadError):
            cls.from_bytes(raw)


def test_types_of_every_declared_field_are_checked():
    with pytest.raises(topics.PayloadError, match="'frames' must be an integer"):
        topics.DetectorStatus.from_dict({"t": 1.0, "frames": "many", "stale_frames": 0, "crc_errors": 0})
    with pytest.raises(topics.PayloadError, match="'phase' must be a string"):
        topics.MissionState.from_dict({"t": 1.0, "phase": [1]})
    with pytest.raises(topics.PayloadError, match="'speedup'"):
        topics.SimClock.from_dict({"t": 1.0, "speedup": 0})
    with pytest.raises(topics.PayloadError, match=r"dwell_points\[1\]"):
        topics.Plan.from_dict({"t": 1.0, "dwell_points": [1.0, float("nan"), 1.5, 0.0]})
    with pytest.raises(topics.PayloadError, match=r"'dwell_points'.*a multiple of 4 numbers, got 3"):
        topics.Plan.from_dict({"t": 1.0, "dwell_points": [1.0, 2.0, 1.5]})  # one point is x, y, z and yaw


def _rows(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with open(path) as fh:
        return list(csv.DictReader(fh))


@pytest.mark.slow
def test_running_mission_drops_impossible_histograms_and_nested_json(router, tmp_path):
    from detector_fw_sim.scene import load_scene

    scenario = tmp_path / "scenario.json"
    write_json(scenario, load_scene().scenario().to_dict())
    out = tmp_path / "flight"
    # no autopilot answers: the mission records while it waits for one, which is all this test needs
    mission = Proc("mission", "--scenario", str(scenario), "--out", str(out), "--connect", router,
                   "--url", f"udpin://127.0.0.1:{free_udp_port()}", "--connect-timeout", "3600")
    try:
        with open_session(connect=router) as s:
            block = zenoh.CongestionControl.BLOCK
            pose_pub = s.declare_publisher(topics.key(topics.POSE), congestion_control=block)
            hist_pub = s.declare_publisher(topics.key(topics.HISTOGRAM), congestion_control=block)
            seq = 0

            def send(payload: bytes | None = None) -> None:
                nonlocal seq
                t = 0.1 * (seq + 1)
                for dt in (-0.1, -0.05, 0.0):
                    pose_pub.put(topics.Pose(t=t + dt, x=1.0, y=2.0, z=1.5, yaw=0.0).to_bytes())
                hist_pub.put(payload or json.dumps(_hist(seq)).encode())
                seq += 1

            def wait_rows(n: int) -> list[dict]:
                deadline = time.monotonic() + WAIT_S
                while time.monotonic() < deadline:
                    rows = _rows(out / "frames.csv")
                    if len(rows) >= n:
                        return rows
                    if mission.p.poll() is not None:
                        break
                    send()
                    time.sleep(0.05)
                raise AssertionError(f"the mission recorded < {n} frames; its output: {mission.seen}")

            def put_until_logged(text: str, put) -> int:
                """The router rewrites every radseek put to DROP (radseek.zenoh_qos): one put may be lost under
                load, so a bad payload is sent again until the mission logs it; returns the puts made."""
                for attempt in range(1, 11):
                    put()
                    try:
                        mission.wait_line(text, timeout=10.0)
                        return attempt
                    except AssertionError:
                        if mission.p.poll() is not None:
                            raise
                raise AssertionError(f"the mission never logged {text!r}; its output: {mission.seen}")

            wait_rows(3)  # subscribed and recording
            bad_seqs: list[int] = []

            def bad_histogram() -> None:
                bad_seqs.append(seq)
                send(json.dumps(_hist(seq, [10**20] + [0] * 31)).encode())

            puts = put_until_logged("counts[0] must be an integer in [0, 65535]", bad_histogram)
            puts += put_until_logged("histogram: payload is nested too deeply", lambda: hist_pub.put(NESTED))
            puts += put_until_logged("pose: payload is nested too deeply", lambda: pose_pub.put(NESTED))
            rows = wait_rows(len(_rows(out / "frames.csv")) + 5)
    finally:
        mission.stop()
    while not mission.lines.empty():
        mission.seen.append(mission.lines.get())
    recorded = {int(r["seq"]) for r in rows} | {int(r["seq"]) for r in _rows(out / "frames_flagged.csv")}
    assert not recorded & set(bad_seqs)
    assert len({s for s in recorded if s > max(bad_seqs)}) >= 3  # the stream goes on after the bad payloads
    assert all(int(r[f"c{k:02d}"]) <= 65535 for r in rows for k in range(32))
    text = "\n".join(mission.seen)
    assert 3 <= text.count("dropped invalid sample") <= puts
    assert "Traceback" not in text and "RecursionError" not in text
    ds = read_dataset(out)  # the flight stays readable
    assert len(ds.frames) == len(rows) and ds.frames.counts.max() <= 65535


def test_mission_without_an_autopilot_says_so_and_exits_1(router, tmp_path):
    from detector_fw_sim.scene import load_scene

    scenario = tmp_path / "scenario.json"
    write_json(scenario, load_scene().scenario().to_dict())
    port = free_udp_port()
    proc = subprocess.run([sys.executable, "-m", "radseek_cli", "mission", "--scenario", str(scenario), "--out",
                           str(tmp_path / "flight"), "--connect", router, "--url", f"udpin://127.0.0.1:{port}",
                           "--connect-timeout", "2"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1, proc.stderr
    assert f"no autopilot heartbeat: udpin://127.0.0.1:{port} after 2 s" in proc.stderr
    assert "Traceback" not in proc.stderr
