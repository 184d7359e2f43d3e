"""Topic inspection: `radseek echo`, `radseek topics`, the generated topic table, and zenoh-cli."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from detector_fw_sim.board import Board
from radseek import topics
from radseek.board_wire import encode_frame, frame_to_histogram
from radseek.zenoh_session import open_session
from radseek_cli.echo_cli import BLOCKS, Formatter, flag_text, resolve_key, sparkline
from radseek_cli.inspect_cli import KeyStats, table, topics_markdown

REPO = Path(__file__).resolve().parents[1]
ZENOH_CLI = Path(sys.executable).with_name("zenoh")
WAIT_S = 60.0  # wall deadlines only bound waiting; no assertion here is on how long something took


def histogram(seq: int, counts=None, flags: int = 0) -> topics.Histogram:
    c = np.arange(32) if counts is None else np.asarray(counts)
    return frame_to_histogram(Board().make_frame(seq, c), t=Board().interval(seq)[1], flags=flags)


class Publisher:
    """Publishes on a background thread until stopped: ``items`` is a list of (topic, payload) per tick."""

    def __init__(self, endpoint: str, items, period: float = 0.05):
        self.endpoint, self.items, self.period = endpoint, items, period
        self.stamps: list[float] = []
        self._stop = threading.Event()
        self._th = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        with open_session(connect=self.endpoint) as s:
            pubs = {}
            tick = 0
            while not self._stop.wait(self.period):
                for topic, payload in self.items(tick):
                    if topic not in pubs:
                        pubs[topic] = s.declare_publisher(topics.key(topic))
                    pubs[topic].put(payload)
                self.stamps.append(time.monotonic())
                tick += 1

    def __enter__(self):
        self._th.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._th.join(10)


def run_cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "radseek_cli", *args], capture_output=True, text=True,
                          timeout=timeout)


# ---------------------------------------------------------------------------- pure formatting


def test_sparkline_scales_to_the_largest_channel():
    assert sparkline(list(range(9))) == BLOCKS  # 0..8 of max 8: one level per count, blank for zero
    assert sparkline([0] * 32) == " " * 32
    assert sparkline([1, 1000])[0] == "▁"  # tiny but non-zero is still visible
    # log scale lifts weak channels: log1p(10) / log1p(1000) * 8 = 2.8 -> level 3
    assert sparkline([10, 1000])[0] == "▁" and sparkline([10, 1000], log=True)[0] == BLOCKS[3]


def test_flags_keys_and_lines_are_readable():
    assert flag_text(0) == "-" and flag_text(topics.FLAG_GAP | topics.FLAG_STALE_POSE) == "STALE_POSE,GAP"
    assert flag_text(0x80) == "0x80"
    assert resolve_key("detector/histogram", "uav3") == "radseek/uav3/detector/histogram"
    assert resolve_key("radseek/*/detector/**", "uav0") == "radseek/*/detector/**"
    fmt = Formatter()
    key = topics.key(topics.HISTOGRAM)
    line = fmt.format(key, histogram(4, flags=topics.FLAG_GAP).to_bytes(), wall=0.0)
    # 0+1+...+31 = 496 counts in 0.1 s
    assert "seq=4" in line and "t=    0.500s" in line and "496 cts" in line and "4960.0 cps" in line
    assert sparkline(list(range(32))) in line and "flags=GAP" in line
    raw = encode_frame(Board().make_frame(4, np.arange(32)))
    assert "496 cts" in fmt.format(topics.key(topics.RAW_FRAME), raw, wall=0.1)
    status = topics.DetectorStatus(t=1.0, frames=10, stale_frames=0, crc_errors=2).to_bytes()
    assert "crc_errors=2" in fmt.format(topics.key(topics.DETECTOR_STATUS), status, wall=0.2)
    line, ok = fmt.safe_format(key, b'{"seq": 1}', wall=0.3)
    assert not ok and "missing field" in line and fmt.bad == 1
    line, ok = fmt.safe_format(topics.key(topics.RAW_FRAME), raw[:40], wall=0.4)
    assert not ok and "truncated frame: 40 bytes" in line and fmt.bad == 2


def test_topics_table_shows_wall_and_sim_rates():
    s = KeyStats()
    for i in range(21):
        s.add(100, i * 0.05)  # 20 intervals in 1 s: 20 Hz
    out = table({"radseek/uav0/detector/histogram": s}, {"uav0": 2.0})
    row = out.splitlines()[1].split()
    assert row[:4] == ["radseek/uav0/detector/histogram", "21", "20.0", "10.0"] and row[-1] == "Histogram"


def test_docs_topics_md_is_generated_from_topics_py():
    doc = (REPO / "docs" / "topics.md").read_text()
    assert doc.strip() == topics_markdown().strip(), "regenerate: radseek topics --markdown > docs/topics.md"
    for cls in topics.PAYLOADS.values():
        assert f"{cls.__name__}" in doc


@pytest.mark.io
def test_echo_decodes_a_serial_byte_stream(tmp_path):
    b = Board()
    frames = [encode_frame(b.make_frame(k, np.arange(32))) for k in range(5)]
    bad = bytearray(frames[2])
    bad[50] ^= 0xFF
    stream = b"\x00\xa5garbage" + frames[0] + frames[1] + bytes(bad) + frames[3][:30] + frames[4] + frames[0][:20]
    path = tmp_path / "ttyUSB0.bin"
    path.write_bytes(stream)
    out = run_cli("echo", "--stream", str(path))
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert [int(line.split("seq=")[1].split()[0]) for line in lines] == [0, 1, 4]
    assert all("496 cts" in line for line in lines)
    assert "3 frames, 2 CRC errors, 0 bad headers, 1 truncated" in out.stderr


# ---------------------------------------------------------------------------- over zenoh


def test_echo_prints_readably_and_survives_bad_messages(router):
    bad_hist = {**histogram(2).to_dict(), "counts": [1] * 31}
    corrupted = bytearray(encode_frame(Board().make_frame(3, np.arange(32))))
    corrupted[30] ^= 0x10

    def items(tick):
        return [
            (topics.HISTOGRAM, histogram(tick, flags=topics.FLAG_SATURATED).to_bytes()),
            (topics.HISTOGRAM, b"not json"),
            (topics.HISTOGRAM, json.dumps(bad_hist).encode()),
            (topics.RAW_FRAME, bytes(corrupted)),
            (topics.RAW_FRAME, encode_frame(Board().make_frame(tick, np.arange(32)))),
        ]

    with Publisher(router, items):
        out = run_cli("echo", "--connect", router, "detector/**", "-n", "15")
        js = run_cli("echo", "--connect", router, "detector/histogram", "--json", "-n", "6")
    assert out.returncode == 0, out.stderr
    good = out.stdout.splitlines()
    bad = out.stderr.splitlines()
    assert len(good) + len(bad) == 15 and good and bad
    assert all("|" + sparkline(list(range(32))) + "|" in g and "496 cts" in g for g in good)
    assert any(g.startswith("radseek/uav0/detector/histogram") and "SATURATED" in g for g in good)
    assert any(g.startswith("radseek/uav0/detector/raw") for g in good)
    assert any("not JSON" in b for b in bad) and any("counts" in b for b in bad) and any("CRC" in b for b in bad)
    print("\n".join(["", *good[:2], *bad[:3]]))
    assert js.returncode == 0
    parsed = []
    for line in js.stdout.splitlines():
        key, _, payload = line.partition(" ")
        assert key == "radseek/uav0/detector/histogram"
        try:
            parsed.append(json.loads(payload))
        except json.JSONDecodeError:
            assert payload == "not json"
    assert any(p.get("counts") == list(range(32)) for p in parsed)


def _wait_for(cond, what: str, timeout: float = WAIT_S) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


def test_topics_lists_live_keys_with_rates(router):
    clock = topics.SimClock(t=1.0, speedup=2.0).to_bytes()
    duration = 2.0
    with Publisher(router, lambda tick: [(topics.HISTOGRAM, histogram(tick).to_bytes()),
                                         (topics.SIM_CLOCK, clock)]) as pub:
        _wait_for(lambda: len(pub.stamps) >= 3, "the publisher to publish")
        w0 = time.monotonic()
        out = run_cli("topics", "--connect", router, "--duration", str(duration))
        w1 = time.monotonic()
        during = [s for s in pub.stamps if w0 <= s <= w1]
    assert out.returncode == 0, out.stderr
    print("\n" + out.stdout)
    rows = {line.split()[0]: line.split() for line in out.stdout.splitlines()[1:]}
    hist = rows["radseek/uav0/detector/histogram"]
    clock_row = rows["radseek/uav0/sim/clock"]
    assert hist[-1] == "Histogram" and clock_row[-1] == "SimClock"
    n, hz, sim_hz = int(hist[1]), float(hist[2]), float(hist[3])
    # it saw only what was published while it ran, and enough of it for a rate
    assert 3 <= n <= len(during) + 1, (n, len(during))
    # HZ is messages per wall second between first and last arrival, inside the listening window: so
    # at least (n - 1) / duration, whatever the load (a per-sim-second rate would be half that here)
    assert hz >= (n - 1) / duration - 0.05, (hist, duration)
    # the same stream measured at both ends: loose, since arrivals may bunch on a loaded host
    achieved = (len(during) - 1) / (during[-1] - during[0])
    assert 0.5 * achieved < hz < 2.0 * achieved, (hist, achieved)
    assert sim_hz == pytest.approx(hz / 2.0, abs=0.06)  # sim rate at speed-up 2
    empty = run_cli("topics", "--connect", router, "--duration", "0.5")
    assert "no messages" in empty.stdout


def test_third_party_zenoh_cli_receives_histograms(router):
    """The PyPI tool zenoh-cli, as a client of our router, prints our JSON histograms."""
    exe = str(ZENOH_CLI) if ZENOH_CLI.exists() else shutil.which("zenoh")
    assert exe, "zenoh-cli missing: it is a dev dependency (pip install -e '.[dev]', as `make` does)"
    cli = subprocess.Popen(
        [exe, "--mode", "client", "--connect", router, "--cfg", "scouting/multicast/enabled:false",
         "subscribe", "-k", "radseek/**/histogram", "--decoder", "json", "--line", "{key} {value}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(cli.stdout), daemon=True)
    reader.start()
    try:
        with Publisher(router, lambda tick: [(topics.HISTOGRAM, histogram(tick).to_bytes())]):
            deadline = time.monotonic() + WAIT_S
            while len(lines) < 3 and time.monotonic() < deadline:
                time.sleep(0.1)
    finally:
        cli.terminate()
        cli.wait(10)
    print("\nzenoh-cli printed:\n" + "".join(lines[:2]))
    assert len(lines) >= 3, cli.stderr.read()
    key, _, value = lines[0].partition(" ")
    assert key == "radseek/uav0/detector/histogram"
    msg = topics.Histogram.from_dict(json.loads(value))  # what a third-party tool prints is our schema
    assert msg.counts == list(range(32)) and msg.duration == pytest.approx(0.1)
