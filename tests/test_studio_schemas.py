"""Every channel schema radseek gives Foxglove (the live view's and flight.mcap's) is one Foxglove Studio 1.48 reads,
held without a browser by its reader ported from its bundle (tests/support/studio_reader.py), and is still a
JSON schema `jsonschema` validates radseek's payloads with. The same in the real Studio:
tests/test_live_view_browser.py (opt-in)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field, fields

import jsonschema
import pytest

from radseek import topics
from radseek.board_wire import FRAME_SIZE, Frame, decode_frame, encode_frame
from radseek_io import foxglove_schemas
from radseek_io.mavlink_json import dialect, mavlink_schema
from radseek_io.mcap_log import (
    DECODED_SCHEMA,
    RAW_ENCODING,
    RAW_SCHEMA_ENCODING,
    board_frame_ros1msg,
    decoded_frame,
    decoded_frame_schema,
)
from tests.support.studio_reader import Refused, parse_channel, parse_json_schema, ros1_read, strict_json

#: the forms Studio 1.48 refused in the browser (docs/vehicle.md), with its error for each
REFUSED = [
    ({"live_time": {"anyOf": [{"type": "number"}, {"type": "null"}]}}, "Unsupported type undefined for live_time"),
    ({"roll": {"type": ["number", "null"]}}, 'Unsupported type ["number","null"] for roll'),
    ({"mavpackettype": {"const": "HEARTBEAT"}}, "Unsupported type undefined for mavpackettype"),
    ({"dwell_points": {"type": "array", "items": {"type": "array", "items": {"type": "number"}}}},
     'Unsupported type "array" for array item dwell_points'),
    ({"sources": {"type": "array", "items": {"type": "object", "additionalProperties": {"type": "number"}}}},
     "Cannot convert undefined or null to object"),
]

#: one payload of each topic as radseek sends it, optional fields both present and absent
PAYLOADS = [
    topics.SimClock(t=1.0, speedup=4.0),
    topics.TruthPose(t=1.0, x=1.0, y=2.0, z=1.5, yaw=0.3),
    topics.Pose(t=1.0, x=1.0, y=2.0, z=1.5, yaw=0.3, var_x=0.01),
    topics.Histogram(seq=3, board_time=0.4, t=0.4, duration=0.1, counts=[1] * 32, live_time=0.09, wall_time=1e9),
    topics.Histogram(seq=3, board_time=0.4, t=0.4, duration=0.1, counts=[1] * 32),
    topics.DetectorStatus(t=1.0, frames=10, stale_frames=0, crc_errors=0, last_histogram_t=1.0),
    topics.DetectorStatus(t=1.0, frames=0, stale_frames=0, crc_errors=0),
    topics.MissionState(t=1.0, phase="dwell", dwell_index=2),
    topics.MissionLockstep(t=1.0, until=1.1),
    topics.Estimate(t=9.0, method="mle", sources=[{"x": 4.0, "y": 3.5, "z": 0.0, "cps_at_1m": 900.0}] * 2,
                    background_cps=40.0, covariance=[0.1] * 32, crlb=[0.05] * 32),
    topics.Estimate(t=9.0, method="pf", sources=[{"x": 4.0, "y": 3.5, "z": 0.0, "cps_at_1m": 900.0}],
                    background_cps=40.0, covariance=[0.1] * 16),
    topics.Plan(t=2.0, dwell_points=[1.0, 2.0, 1.5, 0.3, 4.0, 4.0, 1.5, 0.0], path=[0.0, 0.0, 1.5, 0.0] * 3),
    topics.TeamStatus(t=2.0, vehicle="uav1", seq=4, state="fly", reservation=[1.0, 2.0, 1.5, 3.0, 3.0, 1.5],
                      dwells=[{"index": 0, "x": 1.0, "y": 2.0, "z": 1.5, "mean_rate": 60.0, "t_first": 5.0,
                               "t_last": 9.0}], flown=[0.0, 0.0, 1.5] * 4, stamp=1.5, handled_t=1.9),
]


@pytest.mark.parametrize(("props", "error"), REFUSED)
def test_the_ported_reader_refuses_what_studio_refused(props, error):
    with pytest.raises(Refused) as exc:
        parse_json_schema({"type": "object", "properties": props}, "radseek.X")
    assert str(exc.value) == error
    with pytest.raises(Refused, match="Unsupported encoding radseek.board_frame"):  # the raw frames' old encoding
        parse_channel("radseek.board_frame", None, None, None)


def test_every_radseek_payload_schema_is_read_by_studio_with_every_field():
    assert {type(p) for p in PAYLOADS} == set(topics.PAYLOADS.values())
    for cls in topics.PAYLOADS.values():
        schema = topics.json_schema(cls)
        jsonschema.Draft202012Validator.check_schema(schema)
        name = f"radseek.{cls.__name__}"
        types = parse_channel("json", name, "jsonschema", json.dumps(schema).encode())
        assert [f["name"] for f in types[name]] == [f.name for f in fields(cls)]
    est = parse_json_schema(topics.json_schema(topics.Estimate), "E")
    assert [f["name"] for f in est["E.sources"]] == list(topics.ESTIMATE_STATE)  # plottable by name
    assert {f["name"]: f["type"] for f in est["E"]}["covariance"] == "float64"


@pytest.mark.parametrize("msg", PAYLOADS, ids=lambda m: type(m).__name__)
def test_each_payload_is_strict_json_its_schema_validates(msg):
    data = msg.to_bytes()
    payload = strict_json(data)  # as Studio's JSON.parse reads it
    jsonschema.Draft202012Validator(topics.json_schema(type(msg))).validate(payload)
    assert None not in payload.values()  # an optional field that is None is left out, never null
    assert type(msg).from_bytes(data) == msg


def test_a_declaration_studio_cannot_read_gets_no_schema():
    """json_schema refuses to generate what Studio 1.48 would refuse, naming the field."""
    @dataclass(frozen=True)
    class Nested(topics._Payload):
        rows: list[list[float]]

    @dataclass(frozen=True)
    class FreeForm(topics._Payload):
        extra: dict[str, float] = field(default_factory=dict)

    with pytest.raises(TypeError, match="Nested.rows: an array of arrays"):
        topics.json_schema(Nested)
    with pytest.raises(TypeError, match="FreeForm.extra: an object with no declared keys"):
        topics.json_schema(FreeForm)


def test_every_mavlink_schema_is_read_by_studio():
    names = {c.msgname for c in dialect().mavlink_map.values()}
    assert len(names) > 200
    for name in sorted(names) + ["NOT_IN_THE_DIALECT"]:
        types = parse_channel("json", f"mavlink.{name}", "jsonschema", json.dumps(mavlink_schema(name)).encode())
        assert types[f"mavlink.{name}"][0] == {"name": "mavpackettype", "type": "string", "isArray": False}


def test_the_foxglove_and_decoded_frame_schemas_are_read_by_studio():
    for name in foxglove_schemas.NAMES:
        parse_json_schema(foxglove_schemas.schema(name), f"foxglove.{name}")
    parse_json_schema(decoded_frame_schema(), DECODED_SCHEMA)
    frame = encode_frame(Frame(seq=7, board_time_us=800_000, integration_us=100_000, flags=1,
                               counts=tuple(range(32))))
    for payload in (decoded_frame(frame, 0.8), decoded_frame(frame[:40], 0.8)):
        jsonschema.Draft202012Validator(decoded_frame_schema()).validate(strict_json(json.dumps(payload).encode()))


def test_the_raw_frame_is_its_ros1_message_byte_for_byte():
    """The raw channel is ros1 with a ros1msg schema (which Studio takes); read as ROS 1 reads it, the 90 board
    bytes give the fields decode_frame gives."""
    text = board_frame_ros1msg()
    assert parse_channel(RAW_ENCODING, topics.RAW_FRAME_SCHEMA, RAW_SCHEMA_ENCODING, text.encode()) is None
    f = Frame(seq=123456, board_time_us=12_345_700_000, integration_us=100_000, flags=2,
              counts=tuple(65535 - 7 * k for k in range(32)))
    data = encode_frame(f)
    msg = ros1_read(text, data)
    assert len(data) == FRAME_SIZE and decode_frame(data) == f
    assert (msg["seq"], msg["board_time_us"], msg["integration_us"], msg["status"]) == (123456, 12_345_700_000,
                                                                                        100_000, 2)
    assert tuple(msg["counts"]) == f.counts and msg["sync"] == [0xA5, 0x5A] and msg["length"] == FRAME_SIZE
