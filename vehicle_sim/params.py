"""The parameter protocol as PX4 answers it: a fixed table of named REAL32 / INT32 parameters with bounds and PX4
names; INT32 values travel bytewise in PARAM_VALUE's float (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE, as
PX4 and MAVSDK do).

A request that cannot be served is answered with PARAM_ERROR (MAVLink common, id 345) so that a client fails fast
instead of retrying into a timeout: an unknown name or index (MAV_PARAM_ERROR_DOES_NOT_EXIST), a value out of the
parameter's bounds or not finite (MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE, followed by the unchanged PARAM_VALUE the
protocol asks for), a read-only parameter (MAV_PARAM_ERROR_READ_ONLY, same). MAVSDK maps these to
``ParamResult.Result.DOES_NOT_EXIST`` / ``VALUE_OUT_OF_RANGE`` / ``READ_ONLY``.
"""

from __future__ import annotations

import logging
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as M

log = logging.getLogger(__name__)
REAL32, INT32 = M.MAV_PARAM_TYPE_REAL32, M.MAV_PARAM_TYPE_INT32
_INT_TYPES = {M.MAV_PARAM_TYPE_INT8, M.MAV_PARAM_TYPE_INT16, M.MAV_PARAM_TYPE_INT32, M.MAV_PARAM_TYPE_UINT8,
              M.MAV_PARAM_TYPE_UINT16, M.MAV_PARAM_TYPE_UINT32}


@dataclass
class Param:
    name: str
    value: float
    lo: float
    hi: float
    unit: str
    apply: Callable[[float], None] | None = None
    ptype: int = REAL32  # MAV_PARAM_TYPE: REAL32 or INT32
    default: float = field(init=False)  # the value at boot (the vehicle never saves parameters)

    def __post_init__(self) -> None:
        self.default = self.value

    @property
    def read_only(self) -> bool:
        return self.lo == self.hi


class ParamRefused(ValueError):
    """A set the vehicle refuses: ``error`` is its MAV_PARAM_ERROR, the message says why."""

    def __init__(self, error: int, why: str):
        super().__init__(why)
        self.error = error


def encode(value: float, ptype: int) -> float:
    """PARAM_VALUE's float field for ``value``: INT32 bytewise (PX4), REAL32 as is."""
    if ptype == INT32:
        return struct.unpack("<f", struct.pack("<i", int(value)))[0]
    return float(value)


def decode(raw: float, ptype: int) -> float:
    """The value a PARAM_SET carries: integer types bytewise (PX4, MAVSDK), REAL32 as is."""
    if ptype in _INT_TYPES:
        return float(struct.unpack("<i", struct.pack("<f", raw))[0])
    return float(raw)


class ParamTable:
    def __init__(self, params: list[Param]):
        self._params = params
        self._by_name = {p.name: p for p in params}

    @property
    def params(self) -> list[Param]:
        """The parameters, in index order."""
        return list(self._params)

    def __len__(self) -> int:
        return len(self._params)

    def value_msg(self, p: Param):
        return M.MAVLink_param_value_message(p.name.encode(), encode(p.value, p.ptype), p.ptype,
                                             len(self._params), self._params.index(p))

    def get(self, name: str) -> float:
        return self._by_name[name].value

    def find(self, name: str) -> Param | None:
        return self._by_name.get(name)

    @staticmethod
    def assign(p: Param, v: float) -> None:
        """Set ``p`` to ``v`` as a PARAM_SET or the shell's ``param set`` does: read-only, out of bounds or not finite,
        or refused by its apply hook: ParamRefused (the value unchanged)."""
        if p.read_only and v != p.value:
            raise ParamRefused(M.MAV_PARAM_ERROR_READ_ONLY, f"{p.name} is read-only")
        if not (math.isfinite(v) and p.lo <= v <= p.hi):
            raise ParamRefused(M.MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE, f"{p.name} = {v:g} out of [{p.lo:g}, {p.hi:g}]")
        try:
            if p.apply is not None:
                p.apply(v)
        except ValueError as exc:
            raise ParamRefused(M.MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE, f"{p.name} = {v:g} refused: {exc}") from exc
        p.value = v

    def set(self, name: str, value: float) -> None:
        """Set a parameter from inside the vehicle (its apply hook runs, as for a PARAM_SET)."""
        p = self._by_name[name]
        if p.apply is not None:
            p.apply(value)
        p.value = value

    def handle(self, msg) -> list:
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            return [self.value_msg(p) for p in self._params]
        if kind == "PARAM_REQUEST_READ":
            name = _name(msg.param_id)
            if msg.param_index >= 0:
                if msg.param_index < len(self._params):
                    return [self.value_msg(self._params[msg.param_index])]
                return [_error(msg, name, msg.param_index, M.MAV_PARAM_ERROR_DOES_NOT_EXIST)]
            p = self._by_name.get(name)
            return [self.value_msg(p)] if p else [_error(msg, name, -1, M.MAV_PARAM_ERROR_DOES_NOT_EXIST)]
        if kind == "PARAM_SET":
            name = _name(msg.param_id)
            p = self._by_name.get(name)
            if p is None:
                log.info("PARAM_SET of unknown parameter %r: PARAM_ERROR does-not-exist", name)
                return [_error(msg, name, -1, M.MAV_PARAM_ERROR_DOES_NOT_EXIST)]
            v = decode(float(msg.param_value), int(msg.param_type))
            try:
                self.assign(p, v)
            except ParamRefused as exc:
                log.warning("PARAM_SET refused: %s", exc)
                return [_error(msg, name, self._params.index(p), exc.error), self.value_msg(p)]
            return [self.value_msg(p)]  # the new value confirms
        return []


def _error(msg, name: str, index: int, error: int):
    """PARAM_ERROR back to the sender of ``msg``."""
    return M.MAVLink_param_error_message(msg.get_srcSystem(), msg.get_srcComponent(), name.encode()[:16],
                                         int(index), error)


def _name(raw) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return str(raw).rstrip("\x00")
