"""The order `make test` hands tests to its pytest-xdist workers: longest first, as a greedy list scheduler would
run them on the workers (LPT), with the tests of one ``exclusive`` lock never planned to overlap.

xdist's load scheduler with ``--maxschedchunk 1`` gives each worker the next test in collection order as it
frees up, so the collection order is the schedule. Expected durations are each test's wall seconds in a whole
``make test`` on this kind of machine (``tests/durations.json``, rewritten by ``make durations``); a test not in
it is taken as ``UNKNOWN_SLOW_S`` when marked slow or io and ``UNKNOWN_S`` otherwise. Without a plan, long tests
handed out last keep one worker busy while the others have nothing left, and wall-bound tests (MAVSDK examples,
a Ray cluster) bunched together leave the cores idle.
"""

from __future__ import annotations

import heapq
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TypeVar

T = TypeVar("T")

DURATIONS = Path(__file__).resolve().parent.parent / "durations.json"
#: expected seconds of a test missing from the durations file
UNKNOWN_S, UNKNOWN_SLOW_S = 0.2, 5.0


def load_durations(path: Path = DURATIONS) -> dict[str, float]:
    """nodeid -> expected wall seconds; an absent or unreadable file is no knowledge (every test unknown)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return {str(k): float(v) for k, v in data.items()} if isinstance(data, dict) else {}


def plan(items: Sequence[T], duration: Callable[[T], float], group: Callable[[T], str | None],
         workers: int) -> list[T]:
    """``items`` in the order a greedy scheduler on ``workers`` workers would start them: the longest ready test
    first, where a test of an exclusive group is not ready until the group's previous test is planned to end. If
    every test left is held by its group, the one whose group frees first goes next (it will wait for its lock).
    Ties keep the collection order."""
    ranked = sorted(range(len(items)), key=lambda i: (-duration(items[i]), i))
    free = [0.0] * max(1, workers)  # min-heap of the times the workers free up
    held: dict[str, float] = {}  # group -> planned end of its running test
    out: list[T] = []
    while ranked:
        t = heapq.heappop(free)
        pick = next((k for k, i in enumerate(ranked) if held.get(group(items[i]) or "", 0.0) <= t), None)
        if pick is None:
            pick = min(range(len(ranked)), key=lambda k: (held[group(items[ranked[k]])], k))
        i = ranked.pop(pick)
        g = group(items[i])
        end = max(t, held.get(g, 0.0) if g else 0.0) + duration(items[i])
        if g:
            held[g] = end
        out.append(items[i])
        heapq.heappush(free, end)
    return out
