"""The vehicle's MAVLink handler (``Link.receive`` + ``Vehicle.dispatch``) under hostile input: in-process
(datagrams fed straight to the handler, no thread, no sockets read: fast and deterministic), with
hypothesis property tests of bounded size, plus one fuzz run over real UDP on loopback.

Properties: no datagram crashes the handler; none stops the next valid command from being ACKed; a
forged (wrongly signed) frame moves no state (stream timestamps, our signing clock, the reply address,
the link-loss clock); every COMMAND_LONG/COMMAND_INT is answered by exactly one COMMAND_ACK."""

import logging
import math
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as M

from vehicle_sim.harness import Gcs, VehicleThread, free_udp_port, thread_config
from vehicle_sim.link import SIGNING_EPOCH_S, Link, decode_datagram
from vehicle_sim.vehicle import Vehicle

KEY, WRONG_KEY = bytes(range(32)), bytes(range(100, 132))
GCS_ADDR = ("127.0.0.1", 14550)
AV_ID = M.MAVLINK_MSG_ID_AUTOPILOT_VERSION
TICKS = 100_000  # signing ticks per second
FUZZ = settings(max_examples=300, deadline=None,
                suppress_health_check=[HealthCheck.too_slow])


def now_ticks() -> int:
    return int((time.time() - SIGNING_EPOCH_S) * TICKS)


def encoder(key: bytes | None = None, *, timestamp: int | None = None, link_id: int = 3, sysid: int = 255,
            compid: int = 190) -> M.MAVLink:
    mav = M.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    if key is not None:
        mav.signing.secret_key, mav.signing.sign_outgoing, mav.signing.link_id = key, True, link_id
        mav.signing.timestamp = now_ticks() if timestamp is None else timestamp
    return mav


class InProcess:
    """A Vehicle whose handler is fed datagrams directly; what it sends is recorded, not sent."""

    def __init__(self, signing_key: bytes | None = None):
        self.vehicle = Vehicle(thread_config(free_udp_port(), free_udp_port(), signing_key=signing_key))
        self.ep = self.vehicle.link.endpoints[1]  # the GCS endpoint
        self.sent: list = []
        self.vehicle.link.send = lambda msg, endpoint=None: self.sent.append(msg)
        self.t = 1000.0

    def feed(self, data: bytes) -> list:
        """Hand one datagram to the handler; returns what the vehicle sent in answer."""
        self.t += 0.01
        n = len(self.sent)
        for msg in self.vehicle.link.receive(self.ep, data, GCS_ADDR, self.t):
            self.vehicle.dispatch(self.ep, msg, self.t)
        return self.sent[n:]

    def acks(self, data: bytes, command: int) -> list:
        return [m for m in self.feed(data) if m.get_type() == "COMMAND_ACK" and m.command == command]

    def close(self) -> None:
        self.vehicle.link.close()


@pytest.fixture
def plain():
    h = InProcess()
    yield h
    h.close()


@pytest.fixture
def signed():
    h = InProcess(KEY)
    yield h
    h.close()


def cmd_long(mav: M.MAVLink, command: int, *p: float) -> bytes:
    p = list(p) + [0.0] * (7 - len(p))
    return M.MAVLink_command_long_message(1, 1, command, 0, *p).pack(mav)


def request_av(mav: M.MAVLink) -> bytes:
    return cmd_long(mav, M.MAV_CMD_REQUEST_MESSAGE, AV_ID)


# -- deterministic in-process checks -------------------------------------------------------------------
@pytest.mark.io
def test_parser_keeps_nothing_between_datagrams(plain):
    mav = encoder()
    assert plain.feed(b"\xfd\xff") == []
    assert [a.result for a in plain.acks(cmd_long(mav, 400, 1), 400)] == [M.MAV_RESULT_ACCEPTED]
    valid = request_av(mav)
    for cut in range(1, len(valid)):  # every truncation of a valid frame, then the valid frame
        assert plain.feed(valid[:cut]) == []
        assert len(plain.acks(valid, M.MAV_CMD_REQUEST_MESSAGE)) == 1


def test_decode_datagram_resynchronises_inside_a_datagram():
    mav = encoder()
    a = M.MAVLink_ping_message(1, 1, 0, 0).pack(mav)
    b = cmd_long(mav, 400, 1)
    dec = M.MAVLink(None, 1, 1)
    for data in (a + b, b"\xfd\xff" + a + b, b"junk" + a + b"\xfe\x09" + b, a[:-1] + a + b, a + b + b"\xfd"):
        frames, _ = decode_datagram(dec, data)
        assert [m.get_type() for _, m in frames][-2:] == ["PING", "COMMAND_LONG"], data
    frames, bad = decode_datagram(dec, b"\xfd" * 5000)  # bounded work on a hostile datagram
    assert frames == [] and bad > 0


@pytest.mark.io
def test_forged_frames_move_no_state(signed, caplog):
    h, ep = signed, signed.ep
    gcs = encoder(KEY)
    assert [a.result for a in h.acks(request_av(gcs), M.MAV_CMD_REQUEST_MESSAGE)] == [M.MAV_RESULT_ACCEPTED]
    streams, tx_ts, rx_wall = dict(ep.signature.streams), ep.mav.signing.timestamp, ep.last_rx_wall
    ep.remote = GCS_ADDR
    caplog.set_level(logging.WARNING, logger="vehicle_sim.link")
    forgeries = [
        cmd_long(encoder(WRONG_KEY, timestamp=2**48 - 10), 400, 1),  # the genuine stream id, wrong key
        cmd_long(encoder(WRONG_KEY, timestamp=2**48 - 10, link_id=7, sysid=1, compid=1), 400, 1),  # new stream
        cmd_long(encoder(None), 400, 1),  # unsigned
    ]
    flipped = bytearray(cmd_long(encoder(KEY, timestamp=2**48 - 10), 400, 1))
    flipped[-1] ^= 1  # the right key, one signature bit wrong
    forgeries.append(bytes(flipped))
    for data in forgeries:
        before = h.vehicle.link.stats.rejected_signature
        for msg in h.vehicle.link.receive(ep, data, ("10.6.6.6", 666), h.t + 50):
            h.vehicle.dispatch(ep, msg, h.t + 50)
        assert h.vehicle.link.stats.rejected_signature == before + 1
    assert ep.signature.streams == streams
    assert ep.mav.signing.timestamp < tx_ts + 60 * TICKS
    assert ep.remote == GCS_ADDR and ep.last_rx_wall == rx_wall  # no redirect, the link-loss clock unmoved
    assert not h.vehicle.nav.armed
    assert "wrong signature" in caplog.text and "unsigned" in caplog.text and "refused so far" in caplog.text
    assert [a.result for a in h.acks(request_av(gcs), M.MAV_CMD_REQUEST_MESSAGE)] == [M.MAV_RESULT_ACCEPTED]


@pytest.mark.io
def test_signed_timestamps_must_be_fresh_and_not_far_ahead(signed):
    h, ep = signed, signed.ep
    req = M.MAV_CMD_REQUEST_MESSAGE
    # correctly signed but two hours ahead: refused, and our own signing clock is not dragged there
    assert h.acks(request_av(encoder(KEY, timestamp=now_ticks() + 7200 * TICKS)), req) == []
    assert ep.mav.signing.timestamp < now_ticks() + 60 * TICKS and ep.signature.streams == {}
    assert h.acks(request_av(encoder(KEY, timestamp=2**48 - 10)), req) == []
    # a new stream starting more than a minute in the past: refused (the spec's rule)
    assert h.acks(request_av(encoder(KEY, timestamp=now_ticks() - 120 * TICKS)), req) == []
    gcs = encoder(KEY)
    assert len(h.acks(request_av(gcs), req)) == 1
    replay = request_av(gcs)
    assert len(h.acks(replay, req)) == 1
    assert h.acks(replay, req) == []  # same timestamp again
    other_link = encoder(KEY, link_id=4)  # another link of the same GCS is its own stream
    other_link.signing.timestamp = gcs.signing.timestamp - 50
    assert len(h.acks(request_av(other_link), req)) == 1
    assert h.vehicle.link.stats.rejected_signature == 4


@pytest.mark.io
def test_outgoing_signing_clock_follows_real_time(signed):
    ep = signed.ep
    ep.mav.signing.timestamp -= 3600 * TICKS  # as if it had only counted messages for an hour
    Link.send(signed.vehicle.link, M.MAVLink_heartbeat_message(2, 12, 0, 0, 0, 3), ep)  # the real send
    assert ep.mav.signing.timestamp >= now_ticks() - TICKS


# -- property tests ------------------------------------------------------------------------------------
def base_messages(mav: M.MAVLink) -> list[bytes]:
    """Valid frames of the kinds a GCS sends, packed with ``mav`` (signed if it signs)."""
    nan = math.nan
    msgs = [
        M.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0),
        M.MAVLink_command_long_message(1, 1, M.MAV_CMD_DO_SET_MODE, 0, nan, nan, nan, 0, 0, 0, 0),
        M.MAVLink_command_int_message(1, 1, 6, M.MAV_CMD_DO_REPOSITION, 0, 0, -1, 0, 0, nan, 473977420,
                                      85455940, 10),
        M.MAVLink_ping_message(5, 6, 0, 0),
        M.MAVLink_heartbeat_message(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3),
        M.MAVLink_param_set_message(1, 1, b"MIS_TAKEOFF_ALT", 3.0, M.MAV_PARAM_TYPE_REAL32),
        M.MAVLink_mission_count_message(1, 1, 3, 0),
        M.MAVLink_set_mode_message(1, 1, 0xFFFFFFFF),
        M.MAVLink_statustext_message(4, b"x" * 50),
    ]
    return [m.pack(mav) for m in msgs]


N_BASE = 9
recipes = st.one_of(
    st.tuples(st.just("raw"), st.binary(max_size=400)),
    st.tuples(st.just("header"), st.sampled_from([0xFD, 0xFE]), st.integers(0, 255), st.integers(0, 255),
              st.binary(max_size=300)),
    st.tuples(st.just("truncate"), st.integers(0, N_BASE - 1), st.integers(0, 400)),
    st.tuples(st.just("flip"), st.integers(0, N_BASE - 1),
              st.lists(st.tuples(st.integers(0, 400), st.integers(1, 255)), min_size=1, max_size=4)),
    st.tuples(st.just("forge"), st.integers(0, N_BASE - 1), st.integers(0, 2**48 - 1), st.integers(0, 255),
              st.sampled_from([(255, 190), (1, 1), (255, 0)])),
    st.tuples(st.just("prefix"), st.binary(max_size=20), st.integers(0, N_BASE - 1)),
)
datagrams = st.lists(st.lists(recipes, min_size=1, max_size=3), min_size=1, max_size=4)


def build(recipe, mav: M.MAVLink) -> bytes:
    kind, *a = recipe
    if kind == "raw":
        return a[0]
    if kind == "header":
        return bytes(a[:3]) + a[3]
    base = base_messages(mav)
    if kind == "truncate":
        frame = base[a[0]]
        return frame[:a[1] % len(frame)]  # never the whole frame
    if kind == "flip":
        frame = bytearray(base[a[0]])
        for pos, x in a[1]:
            frame[pos % len(frame)] ^= x
        return bytes(frame)
    if kind == "forge":
        sysid, compid = a[3]
        return base_messages(encoder(WRONG_KEY, timestamp=a[1], link_id=a[2], sysid=sysid, compid=compid))[a[0]]
    return a[0] + base[a[1]]  # prefix


@FUZZ
@given(datagrams)
@pytest.mark.io
def test_fuzzed_datagrams_never_stop_the_next_command(datagram_recipes):
    h = InProcess()
    try:
        gcs = encoder()
        for recipe in datagram_recipes:
            h.feed(b"".join(build(r, gcs) for r in recipe))
        acks = h.acks(request_av(gcs), M.MAV_CMD_REQUEST_MESSAGE)
        assert [a.result for a in acks] == [M.MAV_RESULT_ACCEPTED]
    finally:
        h.close()


@FUZZ
@given(datagrams)
@pytest.mark.io
def test_fuzzed_datagrams_never_lock_out_the_signed_gcs(datagram_recipes):
    h = InProcess(KEY)
    try:
        gcs = encoder(KEY)
        assert len(h.acks(request_av(gcs), M.MAV_CMD_REQUEST_MESSAGE)) == 1
        for recipe in datagram_recipes:
            h.feed(b"".join(build(r, gcs) for r in recipe))
        assert max(h.ep.signature.streams.values()) <= gcs.signing.timestamp  # nothing forged recorded
        assert h.ep.mav.signing.timestamp < now_ticks() + 60 * TICKS
        acks = h.acks(request_av(gcs), M.MAV_CMD_REQUEST_MESSAGE)
        assert [a.result for a in acks] == [M.MAV_RESULT_ACCEPTED]
    finally:
        h.close()


KNOWN_COMMANDS = [400, 22, 21, 20, 17, 176, 300, 224, 192, 178, 511, 512, 520]
anyfloat = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32),
                     st.sampled_from([math.nan, math.inf, -math.inf, 0.0, 1.0, 21196.0, 1e30]))


@FUZZ
@given(st.lists(st.tuples(st.booleans(), st.one_of(st.sampled_from(KNOWN_COMMANDS), st.integers(0, 65535)),
                          st.lists(anyfloat, min_size=7, max_size=7), st.integers(-2**31, 2**31 - 1),
                          st.integers(-2**31, 2**31 - 1), st.sampled_from([0, 3, 5, 6, 99])),
                min_size=1, max_size=6))
@pytest.mark.io
def test_every_command_gets_exactly_one_ack(commands):
    h = InProcess()
    try:
        mav = encoder()
        for as_int, command, p, x, y, frame in commands:
            if as_int:
                msg = M.MAVLink_command_int_message(1, 1, frame, command, 0, 0, *p[:4], x, y, p[6])
            else:
                msg = M.MAVLink_command_long_message(1, 1, command, 0, *p)
            acks = h.acks(msg.pack(mav), command)
            assert len(acks) == 1, (command, p)
            a = acks[0]
            assert a.result in (M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_TEMPORARILY_REJECTED, M.MAV_RESULT_DENIED,
                                M.MAV_RESULT_UNSUPPORTED), (command, p, a)  # FAILED would be a bug
            assert 0 <= a.result_param2 <= 7
            if command not in KNOWN_COMMANDS:
                assert a.result == M.MAV_RESULT_UNSUPPORTED
    finally:
        h.close()


# -- one fuzz run over real UDP ------------------------------------------------------------------------
@pytest.mark.io
def test_fuzzed_datagrams_over_udp():
    gcs_port = free_udp_port()
    vt = VehicleThread(thread_config(free_udp_port(), gcs_port, speedup=5.0))
    with vt as vehicle, Gcs(gcs_port) as gcs:
        gcs.wait_vehicle()

        @settings(max_examples=60, deadline=None,
                  suppress_health_check=[HealthCheck.too_slow])
        @given(datagrams)
        def run(datagram_recipes):
            for recipe in datagram_recipes:
                gcs.send_raw(b"".join(build(r, gcs.mav) for r in recipe))
            assert gcs.command(M.MAV_CMD_REQUEST_MESSAGE, AV_ID, timeout=10) == M.MAV_RESULT_ACCEPTED

        run()
        assert vt.alive
        assert vehicle.link.stats.bad_data > 0
    assert not vt.alive
