"""MAVLink messages as JSON for the MCAP log: a message as a JSON object (pymavlink's ``to_dict()``, byte
arrays as lists, a float field that is NaN, MAVLink's "unknown", left out and a NaN array element null) and
the JSON schema of each message, generated from pymavlink's message definitions (the MAVLink XML it was built
from: field names, C types, array lengths, units, enums), so a tool that reads the log (Foxglove's plot and
raw-message panels, ``jsonschema``) knows every field.

The schemas are in the form Foxglove Studio 1.x's JSON-schema reader takes as well as ``jsonschema``: one
``type`` (a string) per property, the message name a string; a float that may be NaN is a ``number`` the
message leaves out when it is NaN (not required), since JSON has no NaN and that reader takes no
``["number", "null"]``; a float array (fixed length N in MAVLink) lists its element type in ``items`` for such
readers, and ``prefixItems`` (N entries, number or null) says for ``jsonschema`` where null (NaN) may stand.
"""

from __future__ import annotations

import math
import os
from functools import cache
from typing import Any

#: JSON schema of each C type of a MAVLink field (integers with their range)
_INT_RANGES = {
    "uint8_t": (0, 2**8 - 1), "int8_t": (-(2**7), 2**7 - 1), "uint16_t": (0, 2**16 - 1),
    "int16_t": (-(2**15), 2**15 - 1), "uint32_t": (0, 2**32 - 1), "int32_t": (-(2**31), 2**31 - 1),
    "uint64_t": (0, 2**64 - 1), "int64_t": (-(2**63), 2**63 - 1),
}


def dialect():
    """pymavlink's MAVLink 2 common dialect (the messages PX4 and the simulated vehicle speak)."""
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink.dialects.v20 import common

    return common


def jsonable(v: Any) -> Any:
    """A pymavlink field value as JSON: bytes as a list of ints, a float that is not finite (NaN, MAVLink's
    "unknown"; JSON has neither NaN nor infinity) as null."""
    if isinstance(v, bytes | bytearray):
        return list(v)
    if isinstance(v, list | tuple):
        return [jsonable(x) for x in v]
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def message_dict(msg: Any) -> dict[str, Any]:
    """A parsed pymavlink message as the JSON object the log stores (``mavpackettype`` names the message); a
    field that is NaN is left out, a NaN element of an array is null (the module's docstring)."""
    out = {k: jsonable(v) for k, v in msg.to_dict().items()}
    return {k: v for k, v in out.items() if v is not None}


def _field_schema(ctype: str, length: int) -> dict[str, Any]:
    if ctype == "char":  # pymavlink decodes char[N] to a str (one char without a length)
        return {"type": "string"} if not length else {"type": "string", "maxLength": length}
    floating = ctype in ("float", "double")
    if floating:
        item: dict[str, Any] = {"type": "number"}  # a NaN field is left out (message_dict)
    else:
        lo, hi = _INT_RANGES[ctype]
        item = {"type": "integer", "minimum": lo, "maximum": hi}
    if not length:
        return item
    array: dict[str, Any] = {"type": "array", "items": item, "maxItems": length}
    if floating:  # NaN elements are null: allowed at each of the N positions, which leave `items` nothing
        array["prefixItems"] = [{"type": ["number", "null"]}] * length
    return array


@cache
def _classes() -> dict[str, type]:
    return {cls.msgname: cls for cls in dialect().mavlink_map.values()}


@cache
def mavlink_schema(name: str) -> dict[str, Any]:
    """JSON schema (draft 2020-12) of MAVLink message ``name`` (e.g. ``GLOBAL_POSITION_INT``) as
    ``message_dict`` writes it; a name pymavlink's common dialect does not define gets an object schema
    that only names it (``KeyError`` is never raised: an unknown message is still recorded)."""
    cls = _classes().get(name)
    packet_type = {"type": "string", "const": name, "description": "the message's name"}
    base = {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": f"mavlink.{name}",
            "type": "object", "properties": {"mavpackettype": packet_type}}
    if cls is None:
        return {**base, "description": f"MAVLink {name} (not in pymavlink's common dialect: fields unknown)"}
    props: dict[str, Any] = {"mavpackettype": packet_type}
    units, enums = cls.fieldunits_by_name, cls.fieldenums_by_name
    displays = getattr(cls, "fielddisplays_by_name", {})
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))  # in wire order, unlike fieldtypes
    for fname, ctype in zip(cls.fieldnames, cls.fieldtypes, strict=True):
        length = lengths[fname]
        s = _field_schema(ctype, length)
        notes = [ctype + (f"[{length}]" if length else "")]
        if fname in units:
            notes.append(f"unit {units[fname]}")
        if fname in enums:
            notes.append(f"{'bitmask of ' if displays.get(fname) == 'bitmask' else 'enum '}{enums[fname]}")
        s["description"] = ", ".join(notes)
        props[fname] = s
    required = [f for f, ctype in zip(cls.fieldnames, cls.fieldtypes, strict=True)
                if lengths[f] or ctype not in ("float", "double")]  # a NaN float is left out
    return {**base, "description": f"MAVLink {name} (id {cls.id}) as pymavlink's to_dict(), a NaN float left out",
            "properties": props, "required": ["mavpackettype", *required]}
