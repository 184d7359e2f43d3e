"""Invalid payloads a subscriber drops: counted thread-safely, logged without flooding the log.

A zenoh callback decodes each sample with its schema (``radseek.topics``); one that fails is dropped,
counted, and reported the first few times and then every 100th time, so a flood of bad messages
cannot flood the log::

    self._drops = DropCounter(log, "lockstep: dropped invalid message")
    ...
    msg = self._drops.decode(topics.MissionLockstep, sample)
    if msg is None:
        return
"""

from __future__ import annotations

import logging
import threading
from typing import Any, TypeVar

from radseek import topics

T = TypeVar("T")


def worth_reporting(n: int, first: int = 3, every: int = 100) -> bool:
    """Whether the ``n``-th occurrence (from 1) of something repeated is logged: the first ``first``,
    then every ``every``-th one."""
    return n <= first or n % every == 0


class DropCounter:
    """Counts the dropped payloads of one subscriber (``count``) and logs a rate-limited warning
    ``"<what> #<n>: <reason>"`` on ``logger``."""

    def __init__(self, logger: logging.Logger, what: str, *, first: int = 3, every: int = 100):
        self._log = logger
        self._what = what
        self._first = first
        self._every = every
        self._lock = threading.Lock()
        self.count = 0

    def drop(self, reason: Any) -> int:
        """Count one dropped payload (``reason``: the error, or why) and report it if due; its number."""
        with self._lock:
            self.count += 1
            n = self.count
        if worth_reporting(n, self._first, self._every):
            self._log.warning("%s #%d: %s", self._what, n, reason)
        return n

    def decode(self, schema: type[T], sample: Any) -> T | None:
        """``schema.from_bytes`` (a ``radseek.topics`` payload class) of a zenoh sample's payload, or None
        (counted, maybe logged) if it is invalid."""
        try:
            return schema.from_bytes(sample.payload.to_bytes())
        except topics.PayloadError as exc:
            self.drop(exc)
            return None
