"""The order `make test` hands tests to its pytest-xdist workers: longest first, as a greedy list scheduler would
run them on the workers (LPT), with the tests of one ``exclusive`` lock never planned to overlap.

xdist's load scheduler with ``--maxschedchunk 1`` gives each worker the next test in collection order as it
frees up, so the collection order is the schedule. Expected durations are each test's wall seconds in a whole
``make test`` on this kind of machine (``tests/durations.json``, rewritten by ``make durations``); a test not in
it is taken as ``UNKNOWN_SLOW_S`` when marked slow or io and ``UNKNOWN_S`` otherwise. Without a plan, long tests
handed out last keep one worker busy while the others have nothing left, and wall-bound tests (MAVSDK examples,
a Ray cluster) bunched together leave the cores idle.

The file also holds each test's CPU seconds (its processes' included): a worker that frees up takes, among the
:data:`WINDOW` longest ready tests, the longest whose CPU rate (CPU over wall seconds) fits beside the planned
rates of the tests still running, within the machine's cores; when none fits, the one of least rate. Ten-second
MAVSDK examples that mostly wait were planned together by duration alone (the cores 35-50 % idle for half a
minute, a whole run 10 % idle); interleaved with CPU-bound tests of like length they fill the gaps (simulated on a
measured run's per-test CPU and wall: 61 idle core-seconds to 39, the run 12 s shorter).
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
#: the CPU rate of a test missing from the file: a unit test is all CPU; a slow or io one waits half its time
UNKNOWN_RATE, UNKNOWN_SLOW_RATE = 1.0, 0.5
#: how many of the longest ready tests a freed worker chooses among by CPU rate
WINDOW = 8


def load_timings(path: Path = DURATIONS) -> dict[str, tuple[float, float | None]]:
    """nodeid -> (expected wall seconds, CPU seconds or None): entries are ``[wall, cpu]`` or a bare wall (a file
    from before CPU was recorded); an absent or unreadable file, or entry, is no knowledge."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(data, dict):
        return {}
    out: dict[str, tuple[float, float | None]] = {}
    for k, v in data.items():
        if isinstance(v, int | float) and not isinstance(v, bool):
            out[str(k)] = (float(v), None)
        elif isinstance(v, list) and len(v) == 2 and all(isinstance(x, int | float) for x in v):
            out[str(k)] = (float(v[0]), float(v[1]))
    return out


def load_durations(path: Path = DURATIONS) -> dict[str, float]:
    """nodeid -> expected wall seconds (:func:`load_timings`)."""
    return {k: wall for k, (wall, _) in load_timings(path).items()}


def plan(items: Sequence[T], duration: Callable[[T], float], group: Callable[[T], str | None],
         workers: int, rate: Callable[[T], float] | None = None, cores: float = 2.0) -> list[T]:
    """``items`` in the order a greedy scheduler on ``workers`` workers would start them: the longest ready test
    first, where a test of an exclusive group is not ready until the group's previous test is planned to end. If
    every test left is held by its group, the one whose group frees first goes next (it will wait for its lock).
    Ties keep the collection order. With ``rate`` (a test's CPU seconds per wall second), the longest of the
    :data:`WINDOW` longest ready tests whose rate fits beside the running tests' within ``cores``, else the ready
    test of least rate among them."""
    ranked = sorted(range(len(items)), key=lambda i: (-duration(items[i]), i))
    free = [0.0] * max(1, workers)  # min-heap of the times the workers free up
    held: dict[str, float] = {}  # group -> planned end of its running test
    running: list[tuple[float, float]] = []  # (planned end, CPU rate) of the tests planned so far
    out: list[T] = []
    while ranked:
        t = heapq.heappop(free)
        ready = [k for k, i in enumerate(ranked) if held.get(group(items[i]) or "", 0.0) <= t]
        if not ready:
            pick = min(range(len(ranked)), key=lambda k: (held[group(items[ranked[k]])], k))
        elif rate is None:
            pick = ready[0]
        else:
            running = [(end, r) for end, r in running if end > t]
            load = sum(r for _, r in running)
            window = ready[:WINDOW]
            pick = next((k for k in window if load + rate(items[ranked[k]]) <= cores),
                        min(window, key=lambda k: (rate(items[ranked[k]]), k)))
        i = ranked.pop(pick)
        g = group(items[i])
        end = max(t, held.get(g, 0.0) if g else 0.0) + duration(items[i])
        if g:
            held[g] = end
        if rate is not None:
            running.append((end, rate(items[i])))
        out.append(items[i])
        heapq.heappush(free, end)
    return out
