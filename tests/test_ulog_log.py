"""The vehicle's ULog (vehicle_sim.ulog_log, vehicle_sim.px4_logger) read back by pyulog, the parser PX4 Flight
Review and PX4's own tools use: no warning printed, nothing flagged corrupt, and what was logged comes back, a known
position series exactly (values float32 holds exactly), at its sim-time microseconds."""

from __future__ import annotations

import contextlib
import io

import numpy as np
import pytest
from pyulog import ULog

from radseek.coordinates import Home, geodetic_to_enu
from vehicle_sim.navigator import Mode
from vehicle_sim.px4_logger import FORMATS, INTERVAL_S, Px4Logger
from vehicle_sim.telemetry import Snapshot
from vehicle_sim.ulog_log import Format, UlogWriter

HOME = Home(47.397742, 8.545594, 488.0)
PARAMS = [("MPC_XY_CRUISE", 3.0, False), ("SYS_FAILURE_EN", 0, True), ("NAV_ACC_RAD", 0.2, False)]


def parse(data: bytes) -> tuple[ULog, str]:
    """pyulog's reading of ``data`` and what it printed (its warnings go to stdout)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        ulog = ULog(io.BytesIO(data))
    return ulog, out.getvalue()


def snap(t: float, pos, *, armed: bool = False, mode: Mode = Mode.HOLD, battery: float = 1.0) -> Snapshot:
    return Snapshot(t, np.asarray(pos, dtype=float), np.zeros(3), np.zeros(3), 0.3, 0.0, np.array([0.01, 0.04, 0.09,
                    0.001]), armed, not armed, 1, mode, battery, 16.0, HOME, 0, 0, 0, False)


def topic(ulog: ULog, name: str) -> dict:
    return ulog.get_dataset(name).data


def test_a_known_position_series_round_trips_exactly():
    logger = Px4Logger(PARAMS)
    steps = np.arange(0, 201)  # 10 s of 50 ms steps
    east, north, up = 0.25 * steps, -0.5 * steps, 0.125 * steps  # exact in float32
    for k in steps:
        logger.record(snap(k * 0.05, (east[k], north[k], up[k])))
    ulog, printed = parse(logger.read(0, logger.size()))
    assert printed == "" and not ulog.file_corruption
    assert ulog.start_timestamp == 0
    lp = topic(ulog, "vehicle_local_position")
    every = round(INTERVAL_S["vehicle_local_position"] / 0.05)  # 100 ms: every other step
    logged = steps[::every]
    assert np.array_equal(lp["timestamp"], logged * 50_000)  # us of sim time, on the step grid
    assert np.array_equal(lp["x"], north[logged]) and np.array_equal(lp["y"], east[logged])  # NED
    assert np.array_equal(lp["z"], -up[logged])
    att = topic(ulog, "vehicle_attitude")
    assert np.array_equal(att["timestamp"], steps * 50_000)
    # yaw 0.3 rad ENU -> NED pi/2 - 0.3; level: q = (cos, 0, 0, sin) of half the yaw
    assert att["q[0]"][0] == pytest.approx(np.cos((np.pi / 2 - 0.3) / 2), abs=1e-7)
    assert att["q[3]"][0] == pytest.approx(np.sin((np.pi / 2 - 0.3) / 2), abs=1e-7)
    gp = topic(ulog, "vehicle_global_position")
    assert gp["lat"][0] == HOME.lat_deg and gp["lon"][0] == HOME.lon_deg and gp["alt"][0] == np.float32(HOME.alt_m)
    g_logged = steps[::round(INTERVAL_S["vehicle_global_position"] / 0.05)]
    back = np.array([geodetic_to_enu(HOME, la, lo, al)
                     for la, lo, al in zip(gp["lat"], gp["lon"], gp["alt"], strict=True)])
    assert np.allclose(back[:, :2], np.c_[east[g_logged], north[g_logged]], rtol=0, atol=1e-6)  # doubles: um
    assert np.array_equal(back[:, 2], up[g_logged])  # 488 m + k/8 m: exact in float32
    assert back[-1, 1] == pytest.approx(-100.0, abs=1e-6)
    assert lp["eph"][0] == pytest.approx(0.2) and lp["epv"][0] == pytest.approx(0.3)


def test_messages_params_texts_and_changes_as_logged():
    logger = Px4Logger(PARAMS)
    logger.record(snap(0.0, (0, 0, 0)))
    logger.text(0.0, 6, "boot")
    logger.record(snap(0.2, (0, 0, 0), armed=True, mode=Mode.TAKEOFF, battery=0.2))
    logger.param_changed("MPC_XY_CRUISE", 5.5, False)
    logger.text(0.2, 2, "Failsafe: a text longer than the 50 bytes of one STATUSTEXT chunk, logged whole")
    ulog, printed = parse(logger.read(0, logger.size()))
    assert printed == "" and not ulog.file_corruption
    assert {d.name for d in ulog.data_list} == {"vehicle_attitude", "vehicle_local_position",
                                                 "vehicle_global_position", "vehicle_status", "battery_status"}
    assert ulog.msg_info_dict["sys_name"] == "PX4" and ulog.msg_info_dict["ver_hw"] == "PX4_SITL"
    assert ulog.initial_parameters == {"MPC_XY_CRUISE": 3.0, "SYS_FAILURE_EN": 0, "NAV_ACC_RAD": np.float32(0.2)}
    assert isinstance(ulog.initial_parameters["SYS_FAILURE_EN"], int)
    assert ulog.changed_parameters == [(200_000, "MPC_XY_CRUISE", 5.5)]
    assert [(m.log_level_str(), m.timestamp, m.message[:9]) for m in ulog.logged_messages] == \
        [("INFO", 0, "boot"), ("CRITICAL", 200_000, "Failsafe:")]
    st = topic(ulog, "vehicle_status")
    assert list(st["arming_state"]) == [1, 2] and list(st["nav_state"]) == [4, 17]  # PX4: LOITER, TAKEOFF
    assert list(topic(ulog, "battery_status")["warning"]) == [0, 1]  # 20 % <= BAT_LOW_THR 25 %


def test_every_prefix_ending_on_a_message_parses_and_the_bound_keeps_what_was_written():
    logger = Px4Logger(PARAMS, max_bytes=6000)
    t = 0.0
    sizes = []
    while not logger.full:
        logger.record(snap(t, (t, 0, 0)))
        sizes.append(logger.size())
        t += 0.05
    whole = logger.read(0, logger.size())
    assert len(whole) <= 6000 and logger.size() == sizes[-1]
    for size in sizes[::7]:  # what a download started at that moment gets
        ulog, printed = parse(whole[:size])
        assert printed == "" and not ulog.file_corruption
    ulog, _ = parse(whole)
    ts = topic(ulog, "vehicle_attitude")["timestamp"]
    assert np.all(np.diff(ts) == 50_000) and ts[0] == 0  # nothing lost before the bound


def test_the_definitions_go_before_the_data_and_timestamp_first():
    w = UlogWriter()
    fmt = Format("x", (("uint64_t", "timestamp"), ("float[2]", "v")))
    w.add_format(fmt)
    w.subscribe("x")
    with pytest.raises(RuntimeError, match="definitions come first"):
        w.add_format(fmt)
    with pytest.raises(ValueError, match="first field must be 'uint64_t timestamp'"):
        Format("y", (("float", "v"), ("uint64_t", "timestamp")))
    with pytest.raises(ValueError, match="unknown ULog type 'real'"):
        Format("z", (("uint64_t", "timestamp"), ("real", "v")))
    w.write("x", {"timestamp": 7, "v": [1.5, -2.0]})
    ulog, printed = parse(w.read(0, w.size()))
    assert printed == "" and list(ulog.get_dataset("x").data["v[1]"]) == [-2.0]
    assert ulog.message_formats["x"].fields == [("uint64_t", 0, "timestamp"), ("float", 2, "v")]


def test_the_formats_are_those_pyulog_reads_back_field_for_field():
    logger = Px4Logger(PARAMS)
    ulog, _ = parse(logger.read(0, logger.size()))
    for fmt in FORMATS:
        assert ulog.message_formats[fmt.name].fields == [(t.partition("[")[0], int(t.partition("[")[2][:-1] or 0), n)
                                                          for t, n in fmt.fields]
