"""`radseek run` records OUT/flight.mcap: every zenoh topic of the flight and the vehicle's MAVLink telemetry,
readable by the `mcap` reader, and `radseek replay OUT/flight.mcap` reproduces the estimates the mission
flew with. One real flight (all processes, lockstep), checked from every side to save flights: the second of
tests/test_lockstep_repro.py's pair (tests/support/same_seed_runs.py: default scene, 50x, seed 0, flown once per
test run), with 4 dwells so that the search makes two in-flight estimates and the replay also covers the warm
start from one to the next.

That flight is attacked (issue 34, item 1): while it flies, a process without the run's credentials is refused,
and processes holding the detector's and the observer's passwords put a forged sim clock, lockstep and
histograms; the recorder, a subscriber of every key, must log none of them, and the flight is unchanged (the
lockstep test finds it the same as the pair's unattacked first run).
"""

import json
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from launch.stack import Stack, recorder_ready, start_recorder, stop_recorder
from radseek import topics
from radseek.board_wire import decode_frame
from radseek.zenoh_auth import read_credentials
from radseek.zenoh_session import open_session
from radseek_io.dataset import read_dataset
from radseek_io.mcap_frames import read_flight
from tests.support.same_seed_runs import FORGED_SEQ, FORGED_T, RUN_TIMEOUT_S, same_seed_runs
from vehicle_sim.harness import free_udp_port
from vehicle_sim.telemetry import DEFAULT_RATES


@pytest.mark.slow
@pytest.mark.io  # the run's processes, its router and a replay process
@pytest.mark.timeout(RUN_TIMEOUT_S + 400)
def test_run_records_every_topic_and_replay_reproduces_the_flight_from_it(tmp_path_factory):
    from mcap.reader import make_reader

    runs = same_seed_runs(tmp_path_factory)  # the second of the pair is the attacked one
    out, code, stdout, stderr, attack = runs["outs"][1], runs["codes"][1], runs["outs_text"][1], runs["errs"][1], \
        runs["attack"]
    assert code in (0, 3), stderr[-3000:]  # 3: searched to the end of the 4-dwell budget
    assert "recorder" not in stderr, stderr[-3000:]  # no recorder warning: the log is complete
    mission = json.loads((out / "dataset" / "mission_summary.json").read_text())
    summary = json.loads((out / "summary.json").read_text())
    assert summary["estimate_source"] == "in-flight" and len(mission["estimates"]) >= 2, mission

    # --- the mcap reader opens it (footer, summary, index) and finds every topic
    with open(out / "flight.mcap", "rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        messages = [(ch.topic, ch.message_encoding, schema, m) for schema, ch, m in reader.iter_messages()]
    assert header.library == "radseek"
    by_topic: dict[str, list] = {}
    for topic, encoding, schema, m in messages:
        by_topic.setdefault(topic, []).append((encoding, schema, m))
    # every topic radseek/topics.py declares is published in a run: clock, poses and truth pose (vehicle),
    # raw frames, histograms and status (detector), state, lockstep, plan and estimate (mission: this
    # search reached its estimate, asserted above)
    declared = [*(t for t in topics.PAYLOADS if t not in topics.TEAM_ONLY), topics.RAW_FRAME]
    missing = [t for t in declared if topics.key(t) not in by_topic]
    assert not missing, f"not in flight.mcap: {missing}; found {sorted(by_topic)}"
    for name in declared:
        encoding, schema, m = by_topic[topics.key(name)][0]
        if name == topics.RAW_FRAME:
            assert (encoding, schema.encoding, schema.name) == ("ros1", "ros1msg", topics.RAW_FRAME_SCHEMA)
            assert len(decode_frame(m.data).counts) == topics.N_CHANNELS
            continue
        cls = topics.PAYLOADS[name]
        assert encoding == "json" and schema.encoding == "jsonschema" and schema.name == f"radseek.{cls.__name__}"
        assert json.loads(schema.data)["title"] == cls.__name__
        for _, _, msg in by_topic[topics.key(name)]:
            cls.from_bytes(msg.data)  # every recorded payload passes its schema
    # the vehicle's MAVLink telemetry, received as the GCS: every message it streams
    mav_missing = [n for n in DEFAULT_RATES if f"mavlink/{n}" not in by_topic]
    assert not mav_missing, f"MAVLink not in flight.mcap: {mav_missing}"
    heartbeat = json.loads(by_topic["mavlink/HEARTBEAT"][0][2].data)
    assert heartbeat["mavpackettype"] == "HEARTBEAT" and heartbeat["autopilot"] == 12  # PX4
    # the whole flight: from before take-off until the vehicle had landed (the mission's flight time)
    clock = [topics.SimClock.from_bytes(m.data).t for _, _, m in by_topic[topics.key(topics.SIM_CLOCK)]]
    assert min(clock) < 1.0 and max(clock) >= mission["flight_time_s"]

    # --- Foxglove: the well-known channels, every JSON message valid against its schema, times in sim time
    _check_foxglove(by_topic, clock, mission, json.loads((out / "scenario.json").read_text()))
    # --- the attack: refused without credentials; forged puts made in flight, none delivered to anyone
    assert attack["refused"] is not None and "refused a session without credentials" in attack["refused"]
    in_flight = [t for t in attack["clock_at_puts"] if 0 < t < mission["flight_time_s"]]
    assert attack["puts"] > 0 and in_flight, (attack["puts"], attack["clock_at_puts"][-5:])
    assert max(clock) < FORGED_T
    lock = [topics.MissionLockstep.from_bytes(m.data).t for _, _, m in by_topic[topics.key(topics.MISSION_LOCKSTEP)]]
    assert max(lock) < FORGED_T
    hists = [topics.Histogram.from_bytes(m.data) for _, _, m in by_topic[topics.key(topics.HISTOGRAM)]]
    assert not [h for h in hists if h.seq == FORGED_SEQ]
    # the run's secret: private, and never printed nor logged
    creds = out / "zenoh" / "credentials"
    assert creds.stat().st_mode & 0o777 == 0o600
    passwords = [u.password for u in read_credentials(creds)]
    said = stdout + stderr + "".join(p.read_text(errors="replace") for p in (out / "logs").glob("*.log"))
    assert not [p for p in passwords if p in said]
    assert "admitting 5 users" in (out / "logs" / "router.log").read_text()

    # --- the frames rebuilt from the log are the ones the mission recorded (frames.csv rounds to 0.1 mm)
    ds = read_dataset(out / "dataset")
    flight = read_flight(out / "flight.mcap", ds.scenario)
    f, g = ds.frames, flight.frames
    assert len(flight.records) == mission["frames_received"] and flight.dropped == {}
    assert len(g) == len(f) == mission["frames_recorded"]
    np.testing.assert_array_equal(g.dwell, f.dwell)
    np.testing.assert_array_equal(g.counts, f.counts)
    for name in ("t", "duration", "x", "y", "z", "yaw"):
        np.testing.assert_allclose(getattr(g, name), getattr(f, name), rtol=0, atol=5.1e-5, err_msg=name)
    for name in ("var_x", "var_y", "var_z"):  # written with 4 significant digits
        np.testing.assert_allclose(getattr(g, name), getattr(f, name), rtol=5.1e-4, atol=0, err_msg=name)
    assert flight.first_dwell() == mission["estimates"][0]["dwell"]

    # --- radseek replay OUT/flight.mcap gives the estimates the mission flew with, and the final one
    rep = subprocess.run([sys.executable, "-m", "radseek_cli", "replay", str(out / "flight.mcap"), "--json"],
                         capture_output=True, text=True, timeout=600)
    assert rep.returncode == 0, rep.stderr[-3000:]
    rows = json.loads(rep.stdout)
    assert [r["dwells"] for r in rows] == [e["dwell"] for e in mission["estimates"]]
    # The estimate is a deterministic function of the frames, and the rebuilt frames are the mission's
    # in-memory records bit for bit (same JSON payloads, same interpolation): the tolerance, 1 um, only
    # allows for floating-point rounding, far below the estimate's sigma (~0.1 m).
    for row, est in zip(rows, mission["estimates"], strict=True):
        for key in ("x", "y"):
            assert row[key] == pytest.approx(est[key], abs=1e-6), (row["dwells"], key)
    for key in ("x", "y"):
        assert rows[-1][key] == pytest.approx(summary["estimate"][key], abs=1e-6), key
    assert rows[-1]["error_m"] == pytest.approx(summary["error_m"], abs=1e-6)


def _check_foxglove(by_topic, clock, mission, scenario):
    """flight.mcap as Foxglove reads it: the well-known schemas on their channels, every channel one Foxglove Studio
    1.48 reads (tests/support/studio_reader.py), each JSON message strict JSON valid against its channel's schema,
    each raw frame its ros1 message, the raw frames decoded beside them, MAVLink schemas with the real fields,
    and log times in simulation time (an N s simulated flight spans N s of log time)."""
    import jsonschema

    from tests.support.studio_reader import parse_channel, ros1_read, strict_json

    wanted = {"foxglove/uav0/location": "foxglove.LocationFix", "foxglove/uav0/pose": "foxglove.PoseInFrame",
              "foxglove/uav0/truth_pose": "foxglove.PoseInFrame", "foxglove/uav0/tf": "foxglove.FrameTransform",
              "foxglove/map": "foxglove.SceneUpdate", "foxglove/uav0/scene": "foxglove.SceneUpdate"}
    for topic, schema_name in wanted.items():
        assert topic in by_topic, f"{topic} not in flight.mcap"
        encoding, schema, _ = by_topic[topic][0]
        assert (encoding, schema.name, schema.encoding) == ("json", schema_name, "jsonschema"), topic
    validators = {}
    by_topic = {topic: sorted(msgs, key=lambda x: x[2].sequence) for topic, msgs in by_topic.items()}  # as written
    for topic, msgs in by_topic.items():
        last = -1
        for encoding, schema, m in msgs:
            assert m.log_time >= last, f"{topic}: log_time goes back"  # monotonic per channel
            last = m.log_time
            if schema.id not in validators:  # Studio refuses no channel
                parse_channel(encoding, schema.name, schema.encoding, schema.data)
                validators[schema.id] = jsonschema.Draft202012Validator(json.loads(schema.data)) \
                    if encoding == "json" else None
            if encoding != "json":
                ros1_read(schema.data.decode(), m.data)  # the raw frame, every byte of it
                continue
            validators[schema.id].validate(strict_json(m.data))  # JSON.parse takes it: no NaN
    # log time is simulation time: every stamped message at its own time, and the file spans the sim clock
    for topic in (topics.key(topics.SIM_CLOCK), topics.key(topics.POSE), topics.key(topics.HISTOGRAM)):
        for _, _, m in by_topic[topic]:
            assert m.log_time == m.publish_time == round(json.loads(m.data)["t"] * 1e9), topic
    for _, _, m in by_topic["mavlink/GLOBAL_POSITION_INT"]:
        assert m.publish_time == json.loads(m.data)["time_boot_ms"] * 1_000_000
    log_s = [m.log_time / 1e9 for msgs in by_topic.values() for _, _, m in msgs]
    stamped = [m.log_time / 1e9 for topic in (topics.key(topics.SIM_CLOCK), topics.key(topics.POSE),
                                              topics.key(topics.HISTOGRAM)) for _, _, m in by_topic[topic]]
    booted = [d["time_boot_ms"] / 1e3 for topic, msgs in by_topic.items() if topic.startswith("mavlink/")
              for _, _, m in msgs if "time_boot_ms" in (d := json.loads(m.data))]
    # the file spans the sim time its stamped samples carry, so at least the mission's flight time, whatever the
    # speed-up, and no message is logged past the latest sim time a sample carries (the vehicle's time_boot_ms or a
    # zenoh stamp): a wall-clock time would be far past it. At the end the MAVLink (straight over UDP) may run ahead
    # of the zenoh samples (through the router), as the recorder stops both at one wall instant: the router's hop
    # lags by milliseconds of wall, which at 50x on a loaded machine were up to 4.7 simulated seconds (a make test
    # with 4 workers: MAVLink to 97.55 s, zenoh to 92.9 s), and in another the other way round (the vehicle's
    # last time_boot_ms 92.549 s, the clock, poses and histograms to 94.0 s), so the two ends are not compared.
    # Allowed past the latest of those: two of the vehicle's 50 ms steps (there its truth pose, and the HEARTBEAT
    # logged at the time it had reached, were one step on: 94.05 s).
    assert min(log_s) <= min(clock) and max(stamped) <= max(log_s) <= max(max(stamped), max(booted)) + 0.1
    assert max(log_s) - min(log_s) >= mission["flight_time_s"]
    # the map has the walls of the flown scene; the vehicle's scene the plan and the estimate with its ellipses
    scene = json.loads(by_topic["foxglove/uav0/scene"][-1][2].data)
    ids = {e["id"]: e for e in scene["entities"]}
    assert ids["estimate"]["spheres"] and len(ids["estimate"]["lines"]) == 2 and ids["plan"]["spheres"]
    # the map: the flight area's bounds and walls of the scenario the mission flew with (the default scene
    # has no wall: the walls' drawing is checked in tests/test_mcap_foxglove.py)
    first_map = {e["id"]: e for e in json.loads(by_topic["foxglove/map"][0][2].data)["entities"]}
    assert len(first_map["walls"]["cubes"]) == len(scenario["walls"])
    corners = [(p["x"], p["y"]) for p in first_map["bounds"]["lines"][0]["points"]]
    (x0, y0, _), (x1, y1, _) = scenario["bounds"]["min"], scenario["bounds"]["max"]
    assert corners == [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    # the fix is the vehicle's GLOBAL_POSITION_INT, at its time
    fix_m = by_topic["foxglove/uav0/location"][-1][2]
    gpi = [json.loads(m.data) for _, _, m in by_topic["mavlink/GLOBAL_POSITION_INT"]]
    gps = next(g for g in gpi if g["time_boot_ms"] * 1_000_000 == fix_m.log_time)
    assert json.loads(fix_m.data)["latitude"] == gps["lat"] / 1e7
    # the decoded raw frames: one per raw frame, in order, the same counts
    raw = by_topic[topics.key(topics.RAW_FRAME)]
    decoded = by_topic[topics.key(topics.RAW_FRAME) + "/decoded"]
    assert len(decoded) == len(raw) and decoded[0][1].name == "radseek.BoardFrameDecoded"
    for (_, _, r), (_, _, d) in zip(raw, decoded, strict=True):
        assert json.loads(d.data)["counts"] == list(decode_frame(r.data).counts)
    # MAVLink schemas list the real fields
    gpi_schema = json.loads(by_topic["mavlink/GLOBAL_POSITION_INT"][0][1].data)
    assert {"lat", "lon", "alt", "relative_alt", "vx", "vy", "vz", "hdg", "time_boot_ms"} <= set(
        gpi_schema["properties"])


def test_the_launcher_finishes_the_log_it_started(router, tmp_path):
    """run's recorder helpers on a real router: the recorder records, and stopping it (SIGTERM) leaves a
    complete MCAP file the reader opens, with what was published meanwhile."""
    from mcap.reader import make_reader

    stack = Stack(tmp_path / "logs")
    try:
        start_recorder(stack, tmp_path, router, free_udp_port())
        assert recorder_ready(stack, tmp_path) is not None
        with open_session(connect=router) as session:
            for _ in range(20):  # a few puts: the recorder's subscription reaches the router in milliseconds
                session.put(topics.key(topics.MISSION_STATE), topics.MissionState(t=1.0, phase="connect").to_bytes())
                time.sleep(0.1)
        assert stop_recorder(stack, tmp_path) and "recorder" not in stack.procs
    finally:
        stack.stop()
    with open(tmp_path / "flight.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    assert topics.key(topics.MISSION_STATE) in {ch.topic for ch in summary.channels.values()}


def test_a_recorder_that_cannot_start_is_said_and_the_flight_goes_on(router, tmp_path, capsys):
    """The GCS port is taken (say by QGroundControl): the recorder cannot listen there; the launcher says so
    on stderr and carries on without a log instead of failing the flight."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        stack = Stack(tmp_path / "logs")
        try:
            start_recorder(stack, tmp_path, router, taken.getsockname()[1])
            assert recorder_ready(stack, tmp_path) is None
        finally:
            stack.stop()
    err = capsys.readouterr().err
    assert "radseek run: warning: no flight.mcap: the recorder did not start" in err
    assert "recorder.log" in err and "the flight goes on" in err
    assert "unavailable" in (tmp_path / "logs" / "recorder.log").read_text()
    assert not stop_recorder(stack, tmp_path)  # nothing to stop: no second warning
    assert capsys.readouterr().err == ""
