"""The test run's schedule (tests/support/schedule.py): longest first on the workers, an exclusive lock's tests
never planned to overlap, checked by running the planned order through an independent greedy simulation of xdist's
one-test-at-a-time hand-out, in which a test whose lock is held waits for it; CPU-bound and waiting tests
interleaved within the cores."""

import heapq
import json
import os
import subprocess
import sys

import pytest

from tests.support import schedule


def run(order, durations, groups, workers):
    """Makespan and total lock wait when ``workers`` take the next test of ``order`` as they free up."""
    free = [(0.0, w) for w in range(workers)]
    lock_free: dict[str, float] = {}
    waited = 0.0
    end_all = 0.0
    for name in order:
        t, w = heapq.heappop(free)
        g = groups.get(name)
        start = max(t, lock_free.get(g, 0.0)) if g else t
        waited += start - t
        end = start + durations[name]
        if g:
            lock_free[g] = end
        end_all = max(end_all, end)
        heapq.heappush(free, (end, w))
    return end_all, waited


def plan(durations, groups, workers):
    return schedule.plan(list(durations), durations.get, groups.get, workers)


def test_longest_first_on_one_worker_and_ties_keep_collection_order():
    d = {"a": 1.0, "b": 5.0, "c": 3.0, "d": 3.0}
    assert plan(d, {}, 1) == ["b", "c", "d", "a"]


def test_lpt_ends_a_skewed_run_no_later_than_the_bound():
    # 3 workers: one 30 s test collected last, many short ones; collection order ends at 30 + 30 = 60 s at worst
    d = {f"t{i}": 1.0 for i in range(60)} | {"long": 30.0}
    order = plan(d, {}, 3)
    makespan, _ = run(order, d, {}, 3)
    assert order[0] == "long"
    assert makespan == pytest.approx(30.0)  # the 60 one-second tests fit beside it on the two other workers
    assert run(list(d), d, {}, 3)[0] > 40  # the collection order would not


def test_an_exclusive_locks_tests_are_spread_so_no_worker_waits():
    d = {"ray1": 10.0, "ray2": 10.0, "ray3": 9.0} | {f"s{i}": 1.0 for i in range(40)}
    groups = {"ray1": "ray", "ray2": "ray", "ray3": "ray"}
    order = plan(d, groups, 2)
    makespan, waited = run(order, d, groups, 2)
    assert waited == 0.0
    assert makespan == pytest.approx(35.0)  # (29 + 40) / 2 = 34.5: no idle worker but the last second
    naive = sorted(d, key=lambda n: -d[n])  # longest first without the lock: the second ray test waits 10 s
    assert run(naive, d, groups, 2)[1] >= 9.0


def test_only_locked_tests_left_are_taken_in_the_order_their_locks_free():
    d = {"a1": 4.0, "a2": 4.0, "b1": 3.0, "b2": 3.0}
    groups = {"a1": "a", "a2": "a", "b1": "b", "b2": "b"}
    order = plan(d, groups, 4)
    assert order == ["a1", "b1", "b2", "a2"]
    assert run(order, d, groups, 4)[0] == pytest.approx(8.0)


def test_a_missing_or_damaged_durations_file_is_no_knowledge(tmp_path):
    assert schedule.load_durations(tmp_path / "absent.json") == {}
    (tmp_path / "bad.json").write_text("{not json")
    assert schedule.load_durations(tmp_path / "bad.json") == {}
    (tmp_path / "list.json").write_text("[1, 2]")
    assert schedule.load_durations(tmp_path / "list.json") == {}
    (tmp_path / "ok.json").write_text('{"tests/x.py::t": 2.5}')
    assert schedule.load_durations(tmp_path / "ok.json") == {"tests/x.py::t": 2.5}


def test_timings_read_wall_and_cpu_or_a_bare_wall(tmp_path):
    (tmp_path / "t.json").write_text('{"a": [4.0, 3.5], "b": 2.0, "c": [1, "x"], "d": true}')
    assert schedule.load_timings(tmp_path / "t.json") == {"a": (4.0, 3.5), "b": (2.0, None)}
    assert schedule.load_durations(tmp_path / "t.json") == {"a": 4.0, "b": 2.0}


def _peak_rate(order, durations, rates, workers):
    """The largest sum of CPU rates of tests running at once when ``workers`` take ``order`` as they free up."""
    free = [(0.0, w) for w in range(workers)]
    spans = []
    for name in order:
        t, w = heapq.heappop(free)
        spans.append((t, t + durations[name], rates[name]))
        heapq.heappush(free, (t + durations[name], w))
    return max(sum(r for s, e, r in spans if s <= t < e) for t, _, _ in spans)


def test_cpu_bound_and_waiting_tests_are_interleaved_within_the_cores():
    # 4 workers, 2 cores: four CPU-bound tests (rate 1) collected before four that mostly wait (rate 0.1), all 10 s.
    # By duration alone the four CPU-bound ones run together (4 cores' worth on 2); by rate two of each
    d = {f"cpu{i}": 10.0 for i in range(4)} | {f"wait{i}": 10.0 for i in range(4)}
    rates = {n: 1.0 if n.startswith("cpu") else 0.1 for n in d}
    by_duration = plan(d, {}, 4)
    by_rate = schedule.plan(list(d), d.get, {}.get, 4, rates.get, cores=2.0)
    assert by_duration[:4] == ["cpu0", "cpu1", "cpu2", "cpu3"] and _peak_rate(by_duration, d, rates, 4) == 4.0
    assert sorted(by_rate[:4]) == ["cpu0", "cpu1", "wait0", "wait1"]
    assert _peak_rate(by_rate, d, rates, 4) == pytest.approx(2.2)
    assert run(by_rate, d, {}, 4)[0] == run(by_duration, d, {}, 4)[0] == 20.0  # the same wall plan


@pytest.mark.io
def test_record_durations_writes_wall_and_cpu_per_test(tmp_path):
    (tmp_path / "test_two.py").write_text(
        "import time\n"
        "def test_burns():\n    t = time.process_time()\n    while time.process_time() - t < 0.8: pass\n"
        "def test_waits():\n    time.sleep(0.8)\n")
    out, root = tmp_path / "d.json", str(schedule.DURATIONS.parent.parent)
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "tests.conftest",
                        str(tmp_path), "--record-durations", str(out)], capture_output=True, text=True, timeout=120,
                       cwd=tmp_path, env={**os.environ, "PYTHONPATH": root})
    assert r.returncode == 0, r.stdout + r.stderr
    got = json.loads(out.read_text())
    burns, waits = got["test_two.py::test_burns"], got["test_two.py::test_waits"]
    assert burns[0] >= 0.8 and burns[1] >= 0.7  # CPU as long as its wall
    assert waits[0] >= 0.8 and waits[1] < 0.3  # a sleep costs next to no CPU
    assert schedule.load_timings(out)["test_two.py::test_burns"] == tuple(burns)


def test_the_shipped_durations_name_tests_that_exist():
    known = schedule.load_durations()
    assert len(known) > 100
    files = {k.split("::")[0] for k in known}
    missing = [f for f in files if not (schedule.DURATIONS.parent.parent / f).exists()]
    assert not missing, f"tests/durations.json names files that are gone: {missing} (make durations)"
