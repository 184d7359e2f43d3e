"""A minimal parameter protocol: a fixed table of named REAL32 parameters with bounds, PX4 names."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as M

log = logging.getLogger(__name__)


@dataclass
class Param:
    name: str
    value: float
    lo: float
    hi: float
    unit: str
    apply: Callable[[float], None] | None = None


class ParamTable:
    def __init__(self, params: list[Param]):
        self._params = params
        self._by_name = {p.name: p for p in params}

    def __len__(self) -> int:
        return len(self._params)

    def value_msg(self, p: Param):
        return M.MAVLink_param_value_message(p.name.encode(), float(p.value), M.MAV_PARAM_TYPE_REAL32,
                                             len(self._params), self._params.index(p))

    def get(self, name: str) -> float:
        return self._by_name[name].value

    def handle(self, msg) -> list:
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            return [self.value_msg(p) for p in self._params]
        if kind == "PARAM_REQUEST_READ":
            if msg.param_index >= 0:
                return [self.value_msg(self._params[msg.param_index])] if msg.param_index < len(self._params) else []
            p = self._by_name.get(_name(msg.param_id))
            return [self.value_msg(p)] if p else []
        if kind == "PARAM_SET":
            p = self._by_name.get(_name(msg.param_id))
            if p is None:
                log.info("PARAM_SET of unknown parameter %r ignored", msg.param_id)
                return []
            v = float(msg.param_value)
            if math.isfinite(v) and p.lo <= v <= p.hi:
                try:
                    if p.apply is not None:
                        p.apply(v)
                    p.value = v
                except ValueError as exc:
                    log.warning("PARAM_SET %s=%g refused: %s", p.name, v, exc)
            else:
                log.warning("PARAM_SET %s=%g out of [%g, %g]: refused", p.name, v, p.lo, p.hi)
            return [self.value_msg(p)]  # the (possibly unchanged) value confirms or refuses
        return []


def _name(raw) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return str(raw).rstrip("\x00")
