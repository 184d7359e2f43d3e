"""What Foxglove Studio 1.48 (npm @foxglove/studio-base 1.48.0, the last open-source Studio) accepts as a channel,
ported line by line from its bundle (assets/index.js, modules ../mcap-support/src/parseChannel.ts and
parseJsonSchema.ts) so that a test without a browser can hold every schema radseek writes to it. Studio runs
``parseChannel`` on each channel of an MCAP file and each channel a WebSocket server advertises; a channel it
throws on is listed under "Problems" ("Error in topic ...", "Failed to parse channel schema on ...") and its
messages are not shown. The error texts are Studio's. tests/test_live_view_browser.py checks the same in the real
Studio.

Its JSON-schema reader (``parse_json_schema``) takes, at every level:

- an object: ``"type": "object"`` and a ``properties`` object (no ``properties`` is a TypeError in Studio);
- a property: ``oneOf`` only when every alternative is a numeric ``const`` (an enum), else a ``type`` that is one
  *string* among boolean, string (no ``contentEncoding``, or base64), number, integer, object (read
  recursively) and array; ``anyOf``, a list of types, ``null``, or no ``type`` (a bare ``const``) are refused;
- an array's ``items``: one ``type`` among boolean, string (no ``contentEncoding``), number, integer, object; an
  array of arrays is refused.

Every other keyword (``required``, ``prefixItems``, ``minimum``, ``description``, a root ``oneOf``...) is ignored.
"""

from __future__ import annotations

import json
import re
import struct
from typing import Any


class Refused(ValueError):
    """Studio 1.48 refuses the channel (the message is the error Studio shows)."""


def _js(value: Any) -> str:
    """JSON.stringify as Studio's messages print it (undefined for a missing key)."""
    return "undefined" if value is _MISSING else json.dumps(value, separators=(",", ":"))


_MISSING = object()


def parse_json_schema(root: Any, root_name: str) -> dict[str, list[dict[str, Any]]]:
    """Studio's ``parseJsonSchema``: the datatypes (name -> field definitions) of a JSON schema, or Refused."""
    datatypes: dict[str, list[dict[str, Any]]] = {}

    def add_fields(schema: Any, type_name: str, key_path: list[str]) -> None:
        if not isinstance(schema, dict) or schema.get("type", _MISSING) != "object":
            got = schema.get("type", _MISSING) if isinstance(schema, dict) else _MISSING
            raise Refused(f'Expected "type": "object" for schema {type_name}, got {_js(got)}')
        props = schema.get("properties", _MISSING)
        if not isinstance(props, dict):  # Object.entries(undefined) throws in Studio
            raise Refused("Cannot convert undefined or null to object")
        fields: list[dict[str, Any]] = []
        for name, fs in props.items():
            path = ".".join([*key_path, name])
            one_of = fs.get("oneOf", _MISSING)
            if isinstance(one_of, list):
                if all(isinstance(a.get("const"), int | float) and not isinstance(a.get("const"), bool)
                       for a in one_of):
                    fields += [{"name": a.get("title"), "type": "uint32", "isConstant": True} for a in one_of]
                    fields.append({"name": name, "type": "uint32"})
                    continue
                raise Refused(f"Unsupported type for {path}: oneOf alternatives must have number values")
            kind = fs.get("type", _MISSING)
            if kind == "boolean":
                fields.append({"name": name, "type": "bool"})
            elif kind == "string":
                encoding = fs.get("contentEncoding", _MISSING)
                if encoding not in (_MISSING, "base64"):
                    raise Refused(f"Unsupported contentEncoding {_js(encoding)} in {path}")
                fields.append({"name": name, "type": "string" if encoding is _MISSING else "uint8",
                               "isArray": encoding == "base64"})
            elif kind in ("number", "integer"):
                fields.append({"name": name, "type": "float64"})
            elif kind == "object":
                add_fields(fs, f"{type_name}.{name}", [*key_path, name])
                fields.append({"name": name, "type": f"{type_name}.{name}", "isComplex": True})
            elif kind == "array":
                items = fs.get("items", _MISSING)
                if not isinstance(items, dict):  # itemSchema.type of undefined throws in Studio
                    raise Refused(f"Cannot read properties of undefined (reading 'type') at {path}")
                item_kind = items.get("type", _MISSING)
                if item_kind == "boolean":
                    fields.append({"name": name, "type": "bool", "isArray": True})
                elif item_kind == "string":
                    if items.get("contentEncoding", _MISSING) is not _MISSING:
                        raise Refused(f"Unsupported contentEncoding {_js(items['contentEncoding'])} for array "
                                      f"item {path}")
                    fields.append({"name": name, "type": "string", "isArray": True})
                elif item_kind in ("number", "integer"):
                    fields.append({"name": name, "type": "float64", "isArray": True})
                elif item_kind == "object":
                    add_fields(items, f"{type_name}.{name}", [*key_path, name])
                    fields.append({"name": name, "type": f"{type_name}.{name}", "isComplex": True, "isArray": True})
                else:
                    raise Refused(f"Unsupported type {_js(item_kind)} for array item {path}")
            else:
                raise Refused(f"Unsupported type {_js(kind)} for {path}")
        datatypes[type_name] = fields

    add_fields(root, root_name, [])
    return datatypes


#: ROS 1 primitive types and their little-endian ``struct`` codes
ROS1_PRIMITIVES = {"bool": "?", "int8": "b", "uint8": "B", "byte": "b", "char": "B", "int16": "h", "uint16": "H",
                   "int32": "i", "uint32": "I", "int64": "q", "uint64": "Q", "float32": "f", "float64": "d"}
_ROS1_FIELD = re.compile(r"^(\w+)(\[(\d*)\])?\s+(\w+)\s*(=.*)?$")


def ros1_fields(text: str) -> list[tuple[str, str, int | None]]:
    """(name, type, fixed length or None) of a ROS 1 message definition of primitive fields, constants left out;
    Refused for what this reader does not know (a nested type, a string)."""
    out = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        m = _ROS1_FIELD.match(line)
        if not m or m.group(1) not in ROS1_PRIMITIVES:
            raise Refused(f"not a ROS 1 primitive field: {raw!r}")
        if m.group(5):  # a constant: no bytes on the wire
            continue
        if m.group(2) is not None and not m.group(3):
            raise Refused(f"variable-length array (length-prefixed): {raw!r}")
        out.append((m.group(4), m.group(1), int(m.group(3)) if m.group(3) else None))
    return out


def ros1_read(text: str, data: bytes) -> dict[str, Any]:
    """A message of ``ros1_fields`` read from ``data`` as ROS 1 serialises it (little-endian, no padding, fixed
    arrays without a length), every byte used."""
    fmt = "<" + "".join(f"{n or ''}{ROS1_PRIMITIVES[kind]}" for _, kind, n in ros1_fields(text))
    if struct.calcsize(fmt) != len(data):
        raise Refused(f"the definition reads {struct.calcsize(fmt)} bytes, the message has {len(data)}")
    values = list(struct.unpack(fmt, data))
    out = {}
    for name, _, n in ros1_fields(text):
        out[name] = values[:n] if n else values[0]
        del values[:n or 1]
    return out


def parse_channel(message_encoding: str, schema_name: str | None, schema_encoding: str | None,
                  schema_data: bytes | None) -> dict[str, list[dict[str, Any]]] | None:
    """Studio's ``parseChannel`` for the encodings radseek writes (JSON with a JSON schema or none, ROS 1 with a
    ros1msg schema): the JSON datatypes, None for the others it accepts; Refused as Studio refuses."""
    if message_encoding == "json":
        if schema_encoding is not None and schema_encoding != "jsonschema":
            raise Refused(f"Message encoding json with schema encoding '{schema_encoding}' is not supported "
                          "(expected jsonschema or no schema)")
        if schema_encoding is None or not schema_data:
            return {}
        schema = json.loads(schema_data)
        if not isinstance(schema, dict):
            raise Refused(f"Invalid schema, expected JSON object, got {type(schema).__name__}")
        return parse_json_schema(schema, schema_name or "")
    expected = {"ros1": ("ros1msg",), "cdr": ("ros2msg", "ros2idl"), "protobuf": ("protobuf",),
                "flatbuffer": ("flatbuffer",)}
    if message_encoding not in expected:
        raise Refused(f"Unsupported encoding {message_encoding}")
    if schema_encoding not in expected[message_encoding]:
        raise Refused(f"Message encoding {message_encoding} with schema encoding '{schema_encoding}' is not "
                      "supported")
    if message_encoding == "ros1":
        ros1_fields((schema_data or b"").decode())
    return None


def strict_json(data: bytes) -> Any:
    """``JSON.parse`` as Studio deserialises a JSON message: NaN and Infinity, which Python writes, are refused."""
    def refuse(token: str) -> None:
        raise Refused(f"Unexpected token {token} in JSON")

    return json.loads(data, parse_constant=refuse)
