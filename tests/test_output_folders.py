"""Flights are never overwritten or mixed up (issue 12).

`radseek run --out`, `radseek mission --out` and `radseek simulate-dataset --out` refuse a non-empty
folder unless `--force`; with `--force` the command's previous outputs go first (summaries before
data; other files stay), so an aborted run never leaves an old summary beside new partial frames.
Summaries and reports are written atomically, at the end. `radseek run` exits non-zero when the
search fails.

The run tests start the whole stack as real processes on loopback (free ports); they assert on
files, exit codes and log lines, never on wall durations (wall time only bounds waiting)."""

from __future__ import annotations

import csv
import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from launch.stack import EXIT_SEARCH_FAILED, EXIT_USAGE
from mission.recorder import FlightRecorder
from mission.search import search_failure
from radseek_cli.mission_cli import main as mission_main
from radseek_cli.run_cli import main as run_main
from radseek_cli.simulate_cli import main as simulate_main
from radseek_io.dataset import read_scenario, write_json
from radseek_io.outdir import OutputDirError, atomic_path, atomic_write_json, prepare_output
from radseek_io.truth import read_dataset_with_truth
from tests.conftest import free_port
from vehicle_sim.harness import free_udp_port

WAIT_S = 600.0


def _no_temporaries(folder: Path) -> bool:
    return not list(folder.rglob(".tmp-*"))


# ------------------------------------------------------------------------------------------ units


def test_prepare_output_refuses_non_empty_and_force_removes_only_our_outputs(tmp_path):
    out = tmp_path / "flight"
    assert prepare_output(out, force=False, outputs=()) == out and out.is_dir()
    assert prepare_output(out, force=False, outputs=()) == out  # empty: fine
    (out / "summary.json").write_text("{}")
    (out / "dataset").mkdir()
    (out / "dataset" / "frames.csv").write_text("t\n")
    (out / "notes.txt").write_text("mine")
    (out / ".tmp-summary.json.abc").write_text("half")
    with pytest.raises(OutputDirError) as err:
        prepare_output(out, force=False, outputs=("summary.json",))
    assert str(out) in str(err.value) and "--force" in str(err.value)
    assert (out / "summary.json").exists()
    prepare_output(out, force=True, outputs=("summary.json", "dataset"))
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputDirError, match="not a folder"):
        prepare_output(tmp_path / "file", force=True, outputs=())


def test_atomic_write_is_whole_or_nothing(tmp_path):
    target = tmp_path / "summary.json"
    atomic_write_json(target, {"error_m": 0.1})
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text('{"error_m": ')  # a crash half-way through the new summary
        raise RuntimeError("killed")
    assert json.loads(target.read_text()) == {"error_m": 0.1}
    assert _no_temporaries(tmp_path)
    atomic_write_json(target, {"error_m": 0.2})
    assert json.loads(target.read_text()) == {"error_m": 0.2} and _no_temporaries(tmp_path)


def test_recorder_never_truncates_a_recorded_flight(tmp_path):
    from detector_fw_sim.scene import load_scene

    scen = load_scene().scenario()
    with FlightRecorder(tmp_path / "f", scen):
        pass
    with pytest.raises(FileExistsError, match="frames.csv"):
        FlightRecorder(tmp_path / "f", scen)


def test_search_failure_reads_the_mission_verdict():
    est = {"x": 1.0, "y": 2.0}
    assert search_failure({"reason": "source found: 1-sigma 0.080 m < 0.1 m", "outcome": "found", "estimate": est}) \
        is None
    assert search_failure({"reason": "source found: 1-sigma 0.15 m, drift-limited", "outcome": "drift_limited",
                           "estimate": est}) is None
    assert search_failure({"reason": "lattice pattern flown (1-sigma 0.2 m)", "outcome": "pattern_flown",
                           "estimate": est}) is None
    assert search_failure({"reason": "search aborted: vehicle landed", "outcome": "aborted", "estimate": est}) == \
        "search aborted: vehicle landed"
    assert "no source found" in search_failure({"reason": "dwell budget spent (1-sigma 0.4 m)",
                                                "outcome": "budget_spent", "estimate": est})
    misfit = "dwell budget spent (1-sigma 0.04 m; the model misses something, fit p = 0)"
    assert "no source found" in search_failure({"reason": misfit, "outcome": "misfit", "estimate": est})
    assert "no source estimate" in search_failure({"reason": "source found", "outcome": "found", "estimate": None})
    # the verdict is the outcome, never the text: a summary without one did not locate the source
    assert "no source found" in search_failure({"reason": "source found: 1-sigma 0.080 m", "estimate": est})


# ------------------------------------------------------------------------------------------ CLIs


def test_simulate_dataset_refuses_a_non_empty_folder_unless_force(tmp_path, capsys):
    out = tmp_path / "flight"
    assert simulate_main(["--out", str(out)]) == 0
    frames = (out / "frames.csv").read_bytes()
    truth = (out / "truth.json").read_text()
    capsys.readouterr()
    assert simulate_main(["--out", str(out), "--seed", "1"]) == 2
    err = capsys.readouterr().err
    assert str(out) in err and "--force" in err
    assert (out / "frames.csv").read_bytes() == frames and (out / "truth.json").read_text() == truth
    (out / "notes.txt").write_text("mine")
    assert simulate_main(["--out", str(out), "--seed", "1", "--force"]) == 0
    assert (out / "frames.csv").read_bytes() != frames and (out / "notes.txt").read_text() == "mine"
    assert read_dataset_with_truth(out).truth is not None and _no_temporaries(out)
    # --force with a scene that fails: the previous truth is gone, not left beside nothing
    bad = tmp_path / "bad.toml"
    bad.write_text('[[sources]]\nposition = [0, 0, 0]\ncps_at_1m = "lots"\n')
    assert simulate_main(["--out", str(out), "--force", "--scene", str(bad)]) == 2
    assert not (out / "truth.json").exists() and not (out / "frames.csv").exists()


@pytest.mark.io
def test_mission_refuses_a_non_empty_folder_before_connecting(tmp_path, capsys):
    from detector_fw_sim.scene import load_scene

    scenario = tmp_path / "scenario.json"
    write_json(scenario, load_scene().scenario().to_dict())
    out = tmp_path / "flight"
    out.mkdir()
    (out / "frames.csv").write_text("t,duration\n1.0,0.1\n")
    (out / "mission_summary.json").write_text('{"reason": "old"}')
    # nothing listens on this router endpoint: the refusal comes first, at once
    code = mission_main(["--scenario", str(scenario), "--out", str(out), "--connect", f"tcp/127.0.0.1:{free_port()}"])
    assert code == 2
    err = capsys.readouterr().err
    assert str(out) in err and "--force" in err
    assert (out / "frames.csv").read_text() == "t,duration\n1.0,0.1\n"
    assert read_scenario(scenario).background_cps > 0


@pytest.mark.io
def test_run_refuses_a_non_empty_folder(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "summary.json").write_text('{"error_m": 0.15}')
    assert run_main(["--out", str(out), "--quiet", "--zenoh-port", str(free_port())]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert str(out) in err and "--force" in err
    assert (out / "summary.json").read_text() == '{"error_m": 0.15}'
    assert sorted(p.name for p in out.iterdir()) == ["summary.json"]  # nothing started, nothing written


@pytest.mark.io
def test_run_help_documents_exit_codes():
    proc = subprocess.run([sys.executable, "-m", "radseek_cli", "run", "--help"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0
    assert "exit codes:" in proc.stdout and "the search failed" in proc.stdout and "--force" in proc.stdout
    doc = (Path(__file__).resolve().parents[1] / "docs" / "mission.md").read_text()
    assert "Exit codes" in doc and "search aborted" in doc


# ------------------------------------------------------------------------------------------ real runs


def _run_cmd(out: Path, *extra: str) -> tuple[list[str], int]:
    zport = free_port()
    cmd = [sys.executable, "-m", "radseek_cli", "run", "--out", str(out), "--quiet", "--speedup", "20",
           "--zenoh-port", str(zport), "--mavlink-port", str(free_udp_port()), "--gcs-port", str(free_udp_port()),
           "--vehicle-local-ports", f"{free_udp_port()},{free_udp_port()}", "--timeout", str(WAIT_S), *extra]
    return cmd, zport


def _rows(path: Path) -> int:
    try:
        with open(path) as fh:
            return max(sum(1 for _ in csv.reader(fh)) - 1, 0)
    except FileNotFoundError:
        return 0


def _port_free(port: int) -> bool:
    """Nothing listens on the port. SO_REUSEADDR: connections the stopped router closed linger in TIME_WAIT
    for 60 s and would fail a plain bind although no process holds the port."""
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


@pytest.mark.slow
@pytest.mark.timeout(WAIT_S + 300)
def test_aborted_run_leaves_its_frames_and_no_previous_summary(tmp_path):
    out = tmp_path / "run"
    (out / "dataset").mkdir(parents=True)
    # the previous run's results, as a finished `radseek run` leaves them
    stale = {"summary.json": '{"dwell_points": 5, "error_m": 0.15}', "report.png": "png",
             "dataset/truth.json": "{}", "dataset/mission_summary.json": '{"dwell_points": 5}',
             "dataset/frames.csv": "old frames", "flight.mcap": "old log"}
    for name, text in stale.items():
        (out / name).write_text(text)
    (out / "notes.txt").write_text("mine")
    cmd, zport = _run_cmd(out, "--force")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + WAIT_S
        while _rows(out / "dataset" / "frames.csv") < 20:  # the new flight is being recorded
            assert proc.poll() is None, proc.communicate()[1][-3000:]
            assert time.monotonic() < deadline, "no frames recorded"
            time.sleep(0.1)
        for name in ("summary.json", "report.png", "dataset/truth.json", "dataset/mission_summary.json"):
            assert not (out / name).exists(), f"stale {name} beside the new partial frames"
        assert b"old log" not in (out / "flight.mcap").read_bytes()  # --force removed it (the new one is buffered)
        proc.send_signal(signal.SIGTERM)  # the run is aborted mid-flight
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert proc.returncode != 0, stderr[-2000:]
    for name in ("summary.json", "report.png", "dataset/truth.json", "dataset/mission_summary.json"):
        assert not (out / name).exists(), f"{name} after an aborted run"
    assert (out / "notes.txt").read_text() == "mine"
    assert _rows(out / "dataset" / "frames.csv") >= 20  # what was recorded is kept
    assert (out / "dataset" / "frames.csv").read_text().startswith("t,")
    # the MCAP log is finished too (the recorder is stopped with the stack): its footer and index are there
    from radseek_io.mcap_frames import read_flight

    assert len(read_flight(out / "flight.mcap").records) >= 20
    # the stack was stopped with the launcher (its router no longer holds the port)
    deadline = time.monotonic() + 60
    while not _port_free(zport):
        assert time.monotonic() < deadline, "the router outlived the aborted run"
        time.sleep(0.2)


@pytest.mark.slow
@pytest.mark.timeout(WAIT_S + 300)
def test_failed_search_exits_non_zero(tmp_path):
    out = tmp_path / "run"
    # a battery that lasts 50 s: the low-battery failsafe takes the vehicle home mid-search (with lockstep
    # the fits cost no flight time: seed 0 finds the source 82 s into the flight, so 120 s was enough)
    cmd, _ = _run_cmd(out, "--vehicle-arg=--battery-endurance=50")
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=WAIT_S + 120)
    assert proc.returncode == EXIT_SEARCH_FAILED, proc.stderr[-3000:]
    assert "search failed: search aborted" in proc.stderr
    mission = json.loads((out / "dataset" / "mission_summary.json").read_text())
    assert mission["outcome"] == "aborted" and mission["reason"].startswith("search aborted")
    if (out / "summary.json").exists():  # the report is written when the flight allows a fit
        summary = json.loads((out / "summary.json").read_text())
        assert summary["stop_reason"] == mission["reason"] and summary["outcome"] == "aborted"
    assert _no_temporaries(out)


def test_an_output_folder_that_cannot_be_created_is_one_line(tmp_path):
    """A parent that is a file (or a path the system refuses): OutputDirError naming the folder and the reason."""
    from radseek_io.outdir import OutputDirError, prepare_output

    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    with pytest.raises(OutputDirError, match=r"a-file/sub cannot be created or cleared: Not a directory"):
        prepare_output(blocker / "sub", force=False, outputs=())


@pytest.mark.parametrize("argv", [["record", "--out", "{blocked}/flight.mcap"],
                                  ["plan", "--fig4", "{blocked}/fig4.png"],
                                  ["spectra", "export-n42", "{dataset}", "--out", "{blocked}"]])
def test_any_command_names_a_file_it_cannot_write_in_one_line(tmp_path, capsys, shared_datasets, argv):
    """`--out` under a file was a NotADirectoryError traceback from record, plan --fig4, spectra, compare, replay
    --plot and calibrate --plot (issue 34): the `radseek` command says it in one line naming the path, exit 1."""
    from radseek_cli.main import main

    (tmp_path / "a-file").write_text("x")
    blocked = tmp_path / "a-file" / "sub"
    argv = [a.format(blocked=blocked, dataset=shared_datasets / "lattice-clean") for a in argv]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err == f"radseek {argv[0]}: {blocked}: Not a directory (ENOTDIR)\n", err
