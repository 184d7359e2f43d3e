"""A disk write that fails during a flight (the kernel's EFBIG under RLIMIT_FSIZE, as with `ulimit -f`) is named in
one line, the file and the cause, by the mission and by `radseek run`; what was written stays a valid dataset."""

from __future__ import annotations

import resource
import subprocess
import sys

import pytest

from radseek_io.dataset import read_frames
from tests.conftest import free_port
from vehicle_sim.harness import free_udp_port

LIMIT = 40 * 1024  # bytes any process of the run may write to one file: ~185 frames.csv rows, the logs stay below


def _limit_file_size() -> None:
    resource.setrlimit(resource.RLIMIT_FSIZE, (LIMIT, LIMIT))


@pytest.mark.io
def test_a_frame_writer_past_the_file_size_limit_names_the_file_and_keeps_whole_rows(tmp_path):
    code = (
        "import sys\n"
        "from radseek import topics\n"
        "from radseek.frame_record import FrameRecord\n"
        "from radseek_io.dataset import FrameWriter\n"
        "pose = topics.Pose(t=0.0, x=1.0, y=2.0, z=3.0, yaw=0.1, var_x=1e-4, var_y=1e-4, var_z=1e-4)\n"
        "with FrameWriter(sys.argv[1], extra_columns=('seq', 'flags')) as w:\n"
        "    for k in range(100000):\n"
        "        h = topics.Histogram(seq=k, board_time=1.0, t=0.1 * k, duration=0.1, counts=[k % 97] * 32,"
        " flags=0)\n"
        "        try:\n"
        "            w.write(FrameRecord.from_histogram(h, pose, dwell=k // 50))\n"
        "        except OSError as exc:\n"
        "            print(w.rows, w.bytes, exc)\n"
        "            break\n")
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=120,
                       preexec_fn=_limit_file_size)
    assert r.returncode == 0, r.stderr
    rows, size, message = r.stdout.strip().split(" ", 2)
    path = tmp_path / "frames.csv"
    assert message == (f"cannot write {path}: File too large (EFBIG) after {size} bytes; the {rows} rows written "
                       f"stay valid")
    assert path.stat().st_size == int(size) and LIMIT - int(size) < 400  # cut back to the last whole row
    frames = read_frames(path)  # no torn last row: an ordinary read
    assert len(frames) == int(rows) > 100
    assert list(frames.counts[:, 0]) == [k % 97 for k in range(int(rows))]


@pytest.mark.io
@pytest.mark.slow
def test_a_run_whose_dataset_cannot_be_written_says_why_in_its_error_line(tmp_path):
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "radseek_cli", "run", "--out", str(out), "--quiet", "--no-mcap", "--max-dwells", "3",
           "--zenoh-port", str(free_port()), "--mavlink-port", str(free_udp_port()),
           "--gcs-port", str(free_udp_port()), "--vehicle-local-ports", f"{free_udp_port()},{free_udp_port()}",
           "--timeout", "240"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=400, preexec_fn=_limit_file_size)
    frames = out / "dataset" / "frames.csv"
    line = r.stderr.strip().splitlines()[-1]
    assert r.returncode == 1, r.stderr
    assert line.startswith("radseek run: mission failed (exit 1): radseek mission: cannot write "), line
    assert f"{frames}: File too large (EFBIG) after {frames.stat().st_size} bytes" in line, line
    log = (out / "logs" / "mission.log").read_text()
    assert "Traceback" not in log, log[-3000:]
    assert len(read_frames(frames)) > 0  # what was recorded reads as it is
