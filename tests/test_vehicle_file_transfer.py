"""MAVLink FTP and the log protocol against the vehicle over real UDP, with a bare pymavlink ground station:
every request answered (ACK or the spec's NAK code), and the flight log read both ways is the same file, a
telemetry log pymavlink reads back as the vehicle's own messages."""

from __future__ import annotations

import contextlib
import io
import socket
import struct
import time

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as M
from pyulog import ULog

from vehicle_sim.harness import Gcs, VehicleThread, free_udp_port, thread_config
from vehicle_sim.imu import ACCEL_NOISE_DENSITY, GRAVITY, IMU_HZ
from vehicle_sim.mavftp import HEADER

pytestmark = pytest.mark.io


@pytest.fixture
def link():
    gcs_port = free_udp_port()
    with VehicleThread(thread_config(free_udp_port(), gcs_port, speedup=10.0)) as vehicle, Gcs(gcs_port) as gcs:
        gcs.wait_vehicle()
        yield vehicle, gcs


class Ftp:
    """A minimal FTP client: one request, its reply (header fields and data)."""

    def __init__(self, gcs: Gcs):
        self.gcs, self.seq = gcs, 0

    def request(self, opcode: int, data: bytes = b"", *, session: int = 0, offset: int = 0, size: int | None = None,
                seq: int | None = None) -> dict:
        self.seq = self.seq + 1 if seq is None else seq
        head = HEADER.pack(self.seq, session, opcode, len(data) if size is None else size, 0, 0, 0, offset)
        payload = head + data + bytes(251 - len(head) - len(data))
        self.gcs.send(M.MAVLink_file_transfer_protocol_message(0, 1, 1, list(payload)))
        m = self.gcs.recv("FILE_TRANSFER_PROTOCOL", lambda m: _decode(m)["req_opcode"] == opcode, timeout=30)
        return _decode(m)


def _decode(m) -> dict:
    raw = bytes(m.payload) + bytes(251)
    seq, session, opcode, size, req_opcode, burst, _, offset = HEADER.unpack_from(raw)
    return {"seq": seq, "session": session, "opcode": opcode, "size": size, "req_opcode": req_opcode,
            "burst_complete": burst, "offset": offset, "data": raw[HEADER.size:HEADER.size + size],
            "target": (m.target_system, m.target_component)}


def _list(ftp: Ftp, path: str) -> list[str]:
    entries: list[str] = []
    while True:
        r = ftp.request(M.MAV_FTP_OPCODE_LISTDIRECTORY, path.encode(), offset=len(entries))
        if r["opcode"] == M.MAV_FTP_OPCODE_NAK:
            assert r["data"][0] == M.MAV_FTP_ERR_EOF
            return entries
        entries += [e.decode() for e in r["data"].split(b"\x00") if e]


def test_ftp_lists_the_log_folder_and_reads_the_flight_log(link, tmp_path):
    vehicle, gcs = link
    ftp = Ftp(gcs)
    assert _list(ftp, "/") == ["Dfs"]
    days = _list(ftp, "/fs/microsd/log")
    assert len(days) == 1 and days[0].startswith("D")
    files = _list(ftp, f"/fs/microsd/log/{days[0][1:]}")
    assert len(files) == 2 and all(f.startswith("F") for f in files)  # F<name><TAB><size>
    listed = dict(f[1:].split("\t") for f in files)
    assert sorted(n.rsplit(".", 1)[1] for n in listed) == ["tlog", "ulg"]  # PX4's ULog and the telemetry log
    assert len({n.rsplit(".", 1)[0] for n in listed}) == 1  # one boot, one name
    name = next(n for n in listed if n.endswith(".tlog"))
    size = listed[name]
    assert int(size) > 0
    path = f"/fs/microsd/log/{days[0][1:]}/{name}".encode()
    r = ftp.request(M.MAV_FTP_OPCODE_OPENFILERO, path)
    assert r["opcode"] == M.MAV_FTP_OPCODE_ACK and r["seq"] == ftp.seq + 1 and r["target"] == (255, 190)
    session, length = r["session"], struct.unpack("<I", r["data"])[0]
    assert length >= int(size)
    content = b""
    while True:
        r = ftp.request(M.MAV_FTP_OPCODE_READFILE, session=session, offset=len(content), size=239)
        if r["opcode"] == M.MAV_FTP_OPCODE_NAK:
            assert r["data"][0] == M.MAV_FTP_ERR_EOF
            break
        assert r["offset"] == len(content)
        content += r["data"]
    assert len(content) == length
    assert ftp.request(M.MAV_FTP_OPCODE_TERMINATESESSION, session=session)["opcode"] == M.MAV_FTP_OPCODE_ACK
    assert vehicle.flight_log.read(0, length) == content  # the log as it was at opening
    (tmp_path / "flight.tlog").write_bytes(content)
    mlog = mavutil.mavlink_connection(str(tmp_path / "flight.tlog"))
    kinds = []
    while (m := mlog.recv_match()) is not None:
        kinds.append((m.get_type(), m.get_srcSystem()))
    assert ("HEARTBEAT", 1) in kinds and ("GLOBAL_POSITION_INT", 1) in kinds
    assert not any(k == "FILE_TRANSFER_PROTOCOL" for k, _ in kinds)  # the transfer does not feed the log


@pytest.mark.parametrize(("opcode", "data", "error"), [
    (M.MAV_FTP_OPCODE_OPENFILERO, b"@PARAM/param.pck", M.MAV_FTP_ERR_FILENOTFOUND),  # MAVProxy's / QGC's first try
    (M.MAV_FTP_OPCODE_LISTDIRECTORY, b"/fs/nowhere", M.MAV_FTP_ERR_FILENOTFOUND),
    (M.MAV_FTP_OPCODE_READFILE, b"", M.MAV_FTP_ERR_INVALIDSESSION),
    (M.MAV_FTP_OPCODE_CREATEFILE, b"/fs/microsd/x.txt", M.MAV_FTP_ERR_FILEPROTECTED),
    (M.MAV_FTP_OPCODE_REMOVEDIRECTORY, b"/fs/microsd/log", M.MAV_FTP_ERR_FILEPROTECTED),
    (M.MAV_FTP_OPCODE_CALCFILECRC, b"/fs", M.MAV_FTP_ERR_UNKNOWNCOMMAND),
    (42, b"", M.MAV_FTP_ERR_UNKNOWNCOMMAND),
])
def test_ftp_refusals_carry_the_spec_error_code(link, opcode, data, error):
    _, gcs = link
    r = Ftp(gcs).request(opcode, data, session=3)
    assert r["opcode"] == M.MAV_FTP_OPCODE_NAK and r["size"] == 1 and r["data"][0] == error


def test_ftp_resend_gets_the_same_answer_without_a_second_session(link):
    vehicle, gcs = link
    ftp = Ftp(gcs)
    days = _list(ftp, "/fs/microsd/log")
    name = _list(ftp, f"/fs/microsd/log/{days[0][1:]}")[0][1:].split("\t")[0]  # either file
    path = f"/fs/microsd/log/{days[0][1:]}/{name}".encode()
    first = ftp.request(M.MAV_FTP_OPCODE_OPENFILERO, path, seq=100)
    again = ftp.request(M.MAV_FTP_OPCODE_OPENFILERO, path, seq=100)  # the reply was "lost": same seq
    assert first == again and len(vehicle.ftp.sessions) == 1


def _download(gcs: Gcs) -> tuple[object, bytes]:
    """Log 0's LOG_ENTRY and its bytes, by the log protocol."""
    gcs.send(M.MAVLink_log_request_list_message(1, 1, 0, 0xFFFF))
    entry = gcs.recv("LOG_ENTRY")
    gcs.send(M.MAVLink_log_request_data_message(1, 1, 0, 0, entry.size))
    got: dict[int, bytes] = {}
    while sum(len(v) for v in got.values()) < entry.size:
        d = gcs.recv("LOG_DATA")
        got[d.ofs] = bytes(d.data[:d.count])
    return entry, b"".join(got[k] for k in sorted(got))


def test_log_protocol_lists_one_log_and_serves_it_whole(link):
    vehicle, gcs = link
    entry, data = _download(gcs)
    assert (entry.id, entry.num_logs, entry.last_log_num) == (0, 1, 0) and entry.size > 0
    assert abs(entry.time_utc - vehicle.flight_log.boot_wall_s) < 1
    assert data == vehicle.ulog.read(0, entry.size) and data[:7] == b"ULog\x01\x12\x35"  # log 0: the ULog, as PX4
    gcs.send(M.MAVLink_log_request_data_message(1, 1, 0, entry.size + 1000, 90))  # past the end: count 0
    assert gcs.recv("LOG_DATA", lambda d: d.ofs == entry.size + 1000).count == 0


def test_the_downloaded_ulog_is_the_flight_as_pyulog_reads_it(link):
    """A parameter set and a refused command in flight, then the log downloaded: pyulog reads it with no warning,
    with the vehicle's parameters (the change where it happened), its text, and every topic in sim time."""
    vehicle, gcs = link
    gcs.send(M.MAVLink_param_set_message(1, 1, b"MPC_XY_CRUISE", 4.5, M.MAV_PARAM_TYPE_REAL32))
    assert gcs.recv("PARAM_VALUE", lambda m: m.param_id == "MPC_XY_CRUISE").param_value == 4.5
    assert gcs.command(M.MAV_CMD_INJECT_FAILURE, M.FAILURE_UNIT_SENSOR_GPS, M.FAILURE_TYPE_OFF, 0) == \
        M.MAV_RESULT_DENIED  # SYS_FAILURE_EN 0: says so in a STATUSTEXT, sent before the ACK
    assert any(m.get_type() == "STATUSTEXT" and "failure injection disabled" in m.text for m in gcs.received)
    _, data = _download(gcs)
    t_end = vehicle.t
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        ulog = ULog(io.BytesIO(data))
    assert out.getvalue() == "" and not ulog.file_corruption
    assert {d.name for d in ulog.data_list} == {"vehicle_attitude", "vehicle_local_position", "sensor_combined",
                                                 "vehicle_global_position", "vehicle_status", "battery_status"}
    table = {p.name: p for p in vehicle.params.params}
    assert set(ulog.initial_parameters) == set(table)
    for name, p in table.items():
        value = 3.0 if name == "MPC_XY_CRUISE" else p.value  # the table holds the change now; the log both
        integer = p.ptype == M.MAV_PARAM_TYPE_INT32
        assert ulog.initial_parameters[name] == (int(value) if integer else np.float32(value)), name
        assert isinstance(ulog.initial_parameters[name], int) == integer, name
    assert [(n, v) for _, n, v in ulog.changed_parameters] == [("MPC_XY_CRUISE", 4.5)]
    texts = [m for m in ulog.logged_messages if "failure injection disabled" in m.message]
    assert len(texts) == 1 and texts[0].log_level_str() == "INFO"
    for d in ulog.data_list:  # sim time: every 50 ms step from boot, never back, never past the vehicle's clock
        ts = d.data["timestamp"].astype(np.int64)
        assert ts[0] == 0 and np.all(np.diff(ts) > 0) and ts[-1] <= round(t_end * 1e6), d.name
        assert np.all(ts % 50_000 == 0), d.name
    assert ulog.changed_parameters[0][0] <= texts[0].timestamp <= round(t_end * 1e6)
    data = ulog.get_dataset("sensor_combined").data
    dev = np.array([data[f"accelerometer_m_s2[{i}]"] for i in range(3)]) - np.array([[0.0], [0.0], [-GRAVITY]])
    sigma = ACCEL_NOISE_DENSITY * np.sqrt(IMU_HZ)  # PX4 SITL's accelerometer noise, one sample
    assert np.all(np.abs(dev) < 6 * sigma) and np.abs(dev).max() > 1e-3  # standing: (0, 0, -g), with its noise


def test_the_flight_log_holds_the_frames_the_gcs_received_byte_for_byte():
    """The .tlog keeps the bytes the link sent, not a second packing with its own sequence numbers: every datagram
    a ground station received on the GCS port is one of the log's frames, with the same sequence number."""
    api_port, gcs_port = free_udp_port(), free_udp_port()
    with VehicleThread(thread_config(api_port, gcs_port, speedup=10.0)) as vehicle, Gcs(api_port) as api, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", gcs_port))
        sock.settimeout(30)
        received = [sock.recvfrom(65535)[0] for _ in range(100)]
        api.wait_vehicle()  # replies to the API client go to its port alone: the two links' sequences part
        for _ in range(5):
            assert api.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == \
                M.MAV_RESULT_ACCEPTED
        received += [sock.recvfrom(65535)[0] for _ in range(200)]
        time.sleep(0.2)  # the loop records a message as it sends it; give it the last one
        log = vehicle.flight_log.read(0, vehicle.flight_log.size())
    frames, at = [], 0
    while at < len(log):  # 8-byte timestamp, then one MAVLink 2 frame: STX, LEN, INCOMPAT ... + 12 (+13 if signed)
        length = log[at + 9]
        size = 12 + length + (13 if log[at + 10] & 0x01 else 0)
        frames.append(log[at + 8:at + 8 + size])
        at += 8 + size
    assert at == len(log) and all(f[0] == 0xFD for f in frames)
    logged = set(frames)
    missing = [d for d in received if d not in logged]
    assert not missing, f"{len(missing)} of {len(received)} received frames not in the log, e.g. seq {missing[0][4]}"
    seqs = [d[4] for d in received]
    assert len(set(seqs)) > 200  # the control: real sequence numbers, all different over 300 frames
