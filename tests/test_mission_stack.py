"""Hardware-in-loop-style test: `radseek run` with every part its own process over real zenoh and real
MAVLink 2 / UDP on loopback, with the faults of the field injected at once — 10 % MAVLink datagram
loss, a 2 s detector drop-out, corrupted detector frames, and the detector killed (-9) and restarted
mid-mission. The mission must still land with the source found, and every histogram a third party saw
on zenoh during the mission must be in the recorded dataset.

Every timing assertion is on sim time (frame stamps, and the sim time the launcher reports for the
kill); wall time only bounds waiting, generously, so a loaded host slows the test down but does not
fail it. Ports are free ones picked at run time, so two runs on one host do not collide."""

import csv
import json
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from radseek import topics
from radseek.zenoh_session import open_session, session_user
from radseek_io.dataset import read_dataset
from tests.conftest import free_port
from vehicle_sim.harness import free_udp_port

# generous wall bounds for waiting only (the run normally takes a minute or two)
RUN_TIMEOUT_S = 900
pytestmark = [pytest.mark.slow, pytest.mark.timeout(RUN_TIMEOUT_S + 300)]
DROPOUT_AT, KILL_AT = 30.0, 40.0  # sim s: the 2 s detector drop-out, the detector's kill -9


def _seqs(path: Path) -> dict[int, float]:
    out = {}
    for name in ("frames.csv", "frames_flagged.csv"):
        with open(path / name) as fh:
            for row in csv.DictReader(fh):
                out[int(row["seq"])] = float(row["t"])
    return out


def test_mission_survives_injected_faults(tmp_path):
    out = tmp_path / "run"
    PORTS = {"zenoh": free_port(), "mav": free_udp_port(), "gcs": free_udp_port(),
             "local": f"{free_udp_port()},{free_udp_port()}"}
    cmd = [sys.executable, "-m", "radseek_cli", "run", "--out", str(out), "--quiet", "--speedup", "20",
           "--zenoh-port", str(PORTS["zenoh"]), "--mavlink-port", str(PORTS["mav"]), "--gcs-port", str(PORTS["gcs"]),
           "--vehicle-local-ports", PORTS["local"], "--timeout", str(RUN_TIMEOUT_S), "--seed", "3",
           "--vehicle-arg=--drop-rate=0.1",
           # early enough in sim time: with lockstep the fits cost no flight time (the source is found
           # near t = 75 s at seed 3), so faults scheduled later would fall after the landing
           f"--detector-arg=--dropout={DROPOUT_AT}:2", "--detector-arg=--corrupt-rate=0.03",
           "--kill-detector-at", str(KILL_AT)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    seen: dict[int, float] = {}
    lock = threading.Lock()

    def on_hist(sample):
        h = topics.Histogram.from_bytes(sample.payload.to_bytes())
        with lock:
            seen[h.seq] = h.t

    try:
        try:
            # the run's router admits only its users: read the run's credentials (written before the router
            # starts) and watch as its observer
            creds = out / "zenoh" / "credentials"
            while not creds.exists() and proc.poll() is None:
                time.sleep(0.05)
            observer = session_user(None, credentials=creds) if creds.exists() else None
            session_cm = open_session(connect=f"tcp/127.0.0.1:{PORTS['zenoh']}", user=observer,
                                      wait_for_router_s=120)
        except TimeoutError:
            if proc.poll() is not None:  # the launcher died before its router came up: show why
                raise AssertionError(f"radseek run exited {proc.returncode}: {proc.stderr.read()[-3000:]}") from None
            raise
        with session_cm as session:
            sub = session.declare_subscriber(topics.key(topics.HISTOGRAM), on_hist)
            stdout, stderr = proc.communicate(timeout=RUN_TIMEOUT_S + 60)
            sub.undeclare()
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr[-3000:]
    # the launcher reports the sim time at which it killed the detector (it polls, so it is >= KILL_AT)
    kill = re.search(r"detector killed at t=([0-9.]+) s", stderr)
    assert kill, stderr[-3000:]
    t_kill = float(kill.group(1))
    assert t_kill >= KILL_AT

    summary = json.loads((out / "summary.json").read_text())
    # the search ends on its own criterion, within budget, near the source (bound as in
    # test_mission_search: estimator sigma < 0.1 m plus odometry drift of ~0.16 m)
    assert summary["outcome"] in ("found", "drift_limited"), summary["stop_reason"]
    assert summary["error_m"] < 0.5
    assert summary["frames_received"] == summary["frames_recorded"] + summary["frames_flagged"]

    ds = read_dataset(out / "dataset")
    recorded = _seqs(out / "dataset")
    assert len(ds.frames) == summary["frames_recorded"]
    t0, t1 = min(recorded.values()), max(recorded.values())
    # every histogram the independent subscriber saw while the mission was recording is in the dataset
    with lock:
        during = {s for s, t in seen.items() if t0 <= t <= t1}
    missing = sorted(during - set(recorded))
    # save one exception, by design (mission/key_accounts.py): the restarted detector is a new zenoh publisher, and
    # the histogram key passes to it only once its killed owner has been silent OWNER_SILENT_WALL_S; a restart
    # quicker than that (a warm byte-code cache: under 3 s of wall) has its first frames dropped as foreign,
    # counted and named in the mission's log, never silently
    hist = summary["samples"][topics.key(topics.HISTOGRAM)]
    after_kill = [s for s in missing if seen[s] >= t_kill]
    if after_kill:
        assert hist["foreign"] >= len(after_kill), hist
        assert "second publisher on " + topics.key(topics.HISTOGRAM) in (out / "logs" / "mission.log").read_text()
    silent = [s for s in missing if seen[s] < t_kill]
    assert not silent, f"{len(silent)} frames seen on zenoh but not recorded, e.g. {silent[:5]}"

    # the faults really happened: the drop-out and the restart left gaps, the link dropped datagrams
    times = sorted(recorded.values())
    gaps = [(a, b) for a, b in zip(times, times[1:], strict=False) if b - a > 0.15]
    # the 2 s drop-out at t = DROPOUT_AT: frames end at DROPOUT_AT and resume 2.1 s later
    assert any(DROPOUT_AT - 0.5 <= a <= DROPOUT_AT + 0.5 and 1.9 <= b - a <= 2.5 for a, b in gaps), gaps
    # the kill: no frame spans it. The last frame before it ends by the kill time (give or take how far
    # the launcher's view of the clock lagged the detector's), the restarted detector's first frame
    # comes after it, and at least one frame is missing. How much sim time the restart costs depends on
    # wall time: lockstep holds the clock while the detector is away unless it stays silent for
    # mission_process.FRAME_TIMEOUT_WALL_S (then the mission follows the pose), so it may be one frame
    assert any(a <= t_kill + 1.0 and b > t_kill and b - a > 0.15 for a, b in gaps), \
        (t_kill, [g for g in gaps if g[1] > KILL_AT - 10])
    vehicle_log = (out / "logs" / "vehicle.log").read_text()
    dropped = int(vehicle_log.rsplit("dropped-rx ", 1)[1].split()[0])
    assert dropped > 0
