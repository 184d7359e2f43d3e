"""The test run's schedule (tests/support/schedule.py): longest first on the workers, an exclusive lock's tests
never planned to overlap, checked by running the planned order through an independent greedy simulation of xdist's
one-test-at-a-time hand-out, in which a test whose lock is held waits for it."""

import heapq

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


def test_the_shipped_durations_name_tests_that_exist():
    known = schedule.load_durations()
    assert len(known) > 100
    files = {k.split("::")[0] for k in known}
    missing = [f for f in files if not (schedule.DURATIONS.parent.parent / f).exists()]
    assert not missing, f"tests/durations.json names files that are gone: {missing} (make durations)"
