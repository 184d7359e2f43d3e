"""A flight read back from its MCAP log (radseek_io/mcap_frames.py): the frame records the mission's recorder
made, rebuilt from the recorded histogram, pose and mission/state topics, and `radseek replay FILE.mcap`.
Real MCAP files written by the recorder's writer (radseek_io.mcap_log.McapLog); the end-to-end check against
a flown `radseek run` is tests/test_run_mcap.py."""

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from radseek import topics
from radseek.frame_record import FrameRecord
from radseek_cli.replay_cli import main as replay_main
from radseek_cli.replay_cli import replay
from radseek_io.mcap_frames import McapFrameError, beside, read_flight
from radseek_io.mcap_log import McapLog
from radseek_io.truth import read_dataset_with_truth

WALL0 = 1_700_000_000_000_000_000  # ns: log times only order the file


def _write(path, messages):
    """An MCAP file of (topic, payload) in this order, as the recorder writes it."""
    log = McapLog(path)
    for i, (topic, payload) in enumerate(messages):
        data = payload if isinstance(payload, bytes) else payload.to_bytes()
        log.write(topics.key(topic), data, WALL0 + i * 1000)
    log.close()
    return path


def _hist(t, counts=None, flags=0, seq=0):
    counts = counts if counts is not None else [1] * topics.N_CHANNELS
    return topics.Histogram(seq=seq, board_time=t, t=t, duration=0.1, counts=counts, flags=flags)


def _pose(t, x):
    return topics.Pose(t=t, x=x, y=2 * x, z=1.5, yaw=0.0, var_x=0.01 * t, var_y=0.0, var_z=0.0)


def test_records_join_the_pose_at_mid_time_and_the_dwell_of_the_state_before(tmp_path):
    """Poses on the 100 ms step grid, a histogram after each pose, the mission's states stamped with the
    frame they were decided on: the records are the recorder's (pose interpolated at t - 0.05, dwell
    from the last state of an earlier frame), the stale-pose frame is kept but not usable, a payload
    that fails its schema is dropped and counted, and the flight ends with the mission's "done"."""
    msgs = [(topics.MISSION_STATE, topics.MissionState(t=0.0, phase="connect"))]
    for k in range(1, 11):
        t = round(0.1 * k, 10)
        msgs.append((topics.POSE, _pose(t, x=t)))
        msgs.append((topics.HISTOGRAM, _hist(t, flags=topics.FLAG_STALE_POSE if k == 7 else 0, seq=k)))
        if k == 3:  # arrived at the frame ending at 0.3: the dwell starts with the next frame
            msgs.append((topics.MISSION_STATE, topics.MissionState(t=t, phase="dwell", dwell_index=0)))
        if k == 6:  # the dwell ended with the frame ending at 0.6
            msgs.append((topics.MISSION_STATE, topics.MissionState(t=t, phase="search", dwell_index=-1)))
    msgs.append((topics.HISTOGRAM, b'{"t": 1.2}'))  # fails the schema: dropped, as the mission drops it
    # landed at the frame ending at 1.0: the frames the log holds after it are not the flight's
    msgs.append((topics.MISSION_STATE, topics.MissionState(t=1.0, phase="done")))
    msgs += [(topics.POSE, _pose(1.1, 1.1)), (topics.HISTOGRAM, _hist(1.1, seq=11))]
    msgs.append((topics.ESTIMATE, topics.Estimate(t=0.6, method="mle", sources=[], background_cps=1.0,
                                                  covariance=[])))
    flight = read_flight(_write(tmp_path / "f.mcap", msgs))
    assert [r.seq for r in flight.records] == list(range(1, 11))
    assert [r.dwell for r in flight.records] == [-1, -1, -1, 0, 0, 0, -1, -1, -1, -1]
    first = flight.records[0]  # before the first pose: the pose at 0.1 is within the 1 s gap the history allows
    assert (first.x, first.t) == (0.1, 0.1)
    r = flight.records[4]  # frame (0.4, 0.5]: mid-time 0.45, halfway between the poses at 0.4 and 0.5
    assert r.x == pytest.approx(0.45) and r.y == pytest.approx(0.9) and r.var_x == pytest.approx(0.0045)
    expected = FrameRecord.from_histogram(_hist(0.5, seq=5), _pose(0.45, 0.45), 0)
    assert r.values() == pytest.approx(expected.values())
    assert not flight.records[6].usable and len(flight.frames) == 9
    assert flight.dropped == {topics.HISTOGRAM: 1}
    assert flight.first_dwell() == 1 and flight.estimates[0].t == 0.6
    assert flight.end_t == 1.0


def test_a_histogram_waits_for_the_pose_at_its_end(tmp_path):
    """The histogram arrives before the pose of its end time (separate subscriptions): the mission records
    it once that pose is in, so the record interpolates between the poses around its mid-time, not the
    last pose before it."""
    msgs = [(topics.POSE, _pose(0.1, 0.0)), (topics.HISTOGRAM, _hist(0.2)), (topics.POSE, _pose(0.2, 1.0))]
    flight = read_flight(_write(tmp_path / "f.mcap", msgs))
    assert flight.records[0].x == pytest.approx(0.5)
    assert flight.first_dwell() is None and flight.estimates == []


def _as_messages(ds):
    """A recorded flight's topics from a dataset: a pose at each frame's mid-time, the frame's histogram,
    and a mission/state stamped with the last frame before each change of dwell index."""
    f = ds.frames
    msgs = [(topics.MISSION_STATE, topics.MissionState(t=0.0, phase="connect"))]
    for i in range(len(f)):
        t, d = float(f.t[i]), float(f.duration[i])
        if i and f.dwell[i] != f.dwell[i - 1]:
            msgs.append((topics.MISSION_STATE, topics.MissionState(t=float(f.t[i - 1]), phase="x",
                                                                   dwell_index=int(f.dwell[i]))))
        msgs.append((topics.POSE, topics.Pose(t=t - d / 2, x=float(f.x[i]), y=float(f.y[i]), z=float(f.z[i]),
                                              yaw=float(f.yaw[i]), var_x=float(f.var_x[i]), var_y=float(f.var_y[i]),
                                              var_z=float(f.var_z[i]))))
        msgs.append((topics.HISTOGRAM, topics.Histogram(seq=i, board_time=t, t=t, duration=d,
                                                        counts=[int(c) for c in f.counts[i]])))
    if f.dwell[0] >= 0:
        msgs.insert(1, (topics.MISSION_STATE, topics.MissionState(t=0.0, phase="x", dwell_index=int(f.dwell[0]))))
    return msgs


def _replay(capsys, *args: str) -> SimpleNamespace:
    """``radseek replay ARGS`` in this process, as the command line runs it: exit code, stdout and stderr (a
    subprocess each cost ~1.3 s of start-up CPU; the entry point itself: test_replay's CLI test)."""
    capsys.readouterr()
    code = replay_main(list(args))
    out, err = capsys.readouterr()
    return SimpleNamespace(returncode=code, stdout=out, stderr=err)


def test_replay_from_an_mcap_log_is_the_replay_of_its_dataset(shared_datasets, tmp_path, capsys):
    """A reference flight written as topics and read back: the same frames column for column, and `radseek
    replay FILE.mcap` (scenario and truth found beside it in dataset/) gives the dataset's replay."""
    ds = read_dataset_with_truth(shared_datasets / "lattice-clean")  # replay reports the error vs truth
    run = tmp_path / "run"
    (run / "dataset").mkdir(parents=True)
    for name in ("scenario.json", "truth.json"):
        (run / "dataset" / name).write_text((shared_datasets / "lattice-clean" / name).read_text())
    path = _write(run / "flight.mcap", _as_messages(ds))
    flight = read_flight(path, ds.scenario)
    f, g = ds.frames, flight.frames
    for name in ("t", "duration", "x", "y", "z", "yaw", "var_x", "var_y", "var_z", "dwell", "counts"):
        np.testing.assert_array_equal(getattr(g, name), getattr(f, name), err_msg=name)
    assert beside(path, "scenario.json") == run / "dataset" / "scenario.json"
    last = ds.frames.dwell.max() + 1  # the last dwell only: one fit (the machine is shared)
    expected = replay(ds, first_dwell=int(last))
    out = _replay(capsys, str(path), "--from-dwell", str(last), "--json")
    assert out.returncode == 0, out.stderr
    assert f"{len(f)} frames rebuilt from {path}" in out.stderr
    rows = json.loads(out.stdout)
    assert [r["dwells"] for r in rows] == [r["dwells"] for r in expected] == [last]
    for key in ("x", "y", "cps_at_1m", "sigma_m", "error_m"):
        assert rows[0][key] == pytest.approx(expected[0][key], rel=1e-9), key
    assert math.isfinite(rows[0]["error_m"])


def test_unreadable_logs_are_refused_naming_the_file(tmp_path):
    good = _write(tmp_path / "good.mcap", [(topics.POSE, _pose(0.1, 0.0)), (topics.HISTOGRAM, _hist(0.1))])
    data = good.read_bytes()
    cases = {
        "missing.mcap": (None, "no such file"),
        "text.mcap": (b"t,duration,x\n0.1,0.1,0\n", "not an MCAP file"),
        "empty.mcap": (b"", "not an MCAP file"),
        "truncated.mcap": (data[: len(data) // 2], "truncated MCAP file"),
        "cut-footer.mcap": (data[:-3], "truncated MCAP file"),
        "no-flight.mcap": (None, "no valid radseek/uav0/detector/histogram message"),
    }
    _write(tmp_path / "no-flight.mcap", [(topics.POSE, _pose(0.1, 0.0))])
    for name, (content, why) in cases.items():
        if content is not None:
            (tmp_path / name).write_bytes(content)
        with pytest.raises(McapFrameError, match=why) as err:
            read_flight(tmp_path / name)
        assert str(tmp_path / name) in str(err.value), name
    with pytest.raises(McapFrameError, match="not a file"):
        read_flight(tmp_path)
    with pytest.raises(McapFrameError, match="no valid radseek/uav1/detector/histogram"):
        read_flight(good, vehicle="uav1")


def test_replay_cli_says_which_mcap_file_it_cannot_use(shared_datasets, tmp_path, capsys):
    scenario = str(shared_datasets / "lattice-clean" / "scenario.json")
    good = _write(tmp_path / "good.mcap", [(topics.POSE, _pose(0.1, 0.0)), (topics.HISTOGRAM, _hist(0.1))])
    (tmp_path / "bad.mcap").write_text("not mcap")

    def run(*args):
        return _replay(capsys, *args)

    bad = run(str(tmp_path / "bad.mcap"), "--scenario", scenario)
    assert bad.returncode == 2 and f"{tmp_path / 'bad.mcap'}: not an MCAP file" in bad.stderr
    no_scenario = run(str(good))
    assert no_scenario.returncode == 2 and str(good) in no_scenario.stderr and "--scenario" in no_scenario.stderr
    wrong_scenario = run(str(good), "--scenario", str(tmp_path / "none.json"))
    assert wrong_scenario.returncode == 2 and "none.json" in wrong_scenario.stderr
    assert "Traceback" not in bad.stderr + no_scenario.stderr + wrong_scenario.stderr
