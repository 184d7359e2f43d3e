"""`radseek run` on a machine where the default ports are taken (issue 33, item 4): it picks the first free
PX4-style instance and says which ports on one line, refuses a port given by its flag that is in use with the
flag that moves it (never the router's --listen), and two stacks fly side by side without cross-talk.

Real processes over real sockets. The flights use a fast honest configuration (lockstep, 50x, 2-3 dwells:
tests/support/side_by_side_runs.py); assertions are on exit codes, the ports line, logs and outputs, never on
wall-clock time. The two side-by-side runs start while the test occupies the real defaults (7447, 14540): both must
move off them and off each other (a port already held by someone else on this machine is just as taken, and a run
must move either way). Those two runs are flown once and read by the two tests that check them (and by
tests/test_one_world.py).
"""

import json
import re
import socket

import numpy as np
import pytest

from launch import ports as P
from launch.stack import Stack, start_router
from radseek import topics
from radseek_cli.run_cli import main as run_main
from radseek_io.dataset import read_dataset
from radseek_io.mcap_frames import read_flight
from tests.support.side_by_side_runs import RUN_TIMEOUT_S, Held, side_by_side_on_held_defaults

PORTS_LINE = re.compile(r"^radseek run: ports: (?:instance (\d+): )?zenoh tcp/127\.0\.0\.1:(\d+), "
                        r"MAVLink API udp (\d+) .*GCS udp (\d+), .*system id (\d+)", re.M)


def _ports_line(stderr: str) -> dict[str, int | None]:
    lines = PORTS_LINE.findall(stderr)
    assert len(lines) == 1, stderr[-3000:]  # one line, whatever moved
    inst, zenoh, api, gcs, sysid = lines[0]
    return {"instance": int(inst) if inst else None, "zenoh": int(zenoh), "api": int(api), "gcs": int(gcs),
            "sysid": int(sysid)}


def _flew(out, returncode: int, stderr: str) -> dict:
    """The run completed on its own ports: verdict, report, router on the port it named."""
    assert returncode in (0, 3), stderr[-3000:]  # 3: the 2-dwell budget spent before the stop criterion
    assert "recorder" not in stderr, stderr[-3000:]  # flight.mcap complete
    assert (out / "summary.json").is_file() and (out / "report.png").is_file()
    used = _ports_line(stderr)
    assert f"listening on tcp/127.0.0.1:{used['zenoh']}" in (out / "logs" / "router.log").read_text()
    return used


def _own_frames_only(out) -> np.ndarray:
    """The frames the mission recorded are the ones its detector sent on its router, and the recorder on that
    router and on its GCS port saw one vehicle's clock: no frame, clock or pose of the other stack."""
    mission = json.loads((out / "dataset" / "mission_summary.json").read_text())
    ds = read_dataset(out / "dataset")
    f = ds.frames
    assert mission["frames_received"] == mission["frames_recorded"] == len(f)
    assert np.all(np.diff(f.t) > 0)
    flight = read_flight(out / "flight.mcap", ds.scenario)
    assert flight.dropped == {} and len(flight.frames) == len(f)
    np.testing.assert_array_equal(flight.frames.counts, f.counts)
    from mcap.reader import make_reader

    # in the order received (log_time is sim time: sorted by it, two vehicles' clocks would look as one)
    with open(out / "flight.mcap", "rb") as fh:
        clock = [topics.SimClock.from_bytes(m.data).t for _, _, m in sorted(
            make_reader(fh).iter_messages(topics=[topics.key(topics.SIM_CLOCK)], log_time_order=False),
            key=lambda x: x[2].sequence)]
    assert clock and np.all(np.diff(clock) >= 0), "two vehicles' clocks in one recording"
    with open(out / "flight.mcap", "rb") as fh:
        boot = [json.loads(m.data)["time_boot_ms"] for _, _, m in sorted(
            make_reader(fh).iter_messages(topics=["mavlink/LOCAL_POSITION_NED"], log_time_order=False),
            key=lambda x: x[2].sequence)]
    assert boot and np.all(np.diff(boot) >= 0), "two vehicles' MAVLink on one GCS port"
    return f.counts


@pytest.mark.slow
@pytest.mark.io
@pytest.mark.timeout(RUN_TIMEOUT_S + 300)
# runs on the default ports (7447, 14540...): never beside the other test that does (a test bound 14540 between
# this run's port check and its mission's bind)
@pytest.mark.exclusive("default-ports-7447-14540")
def test_run_moves_off_taken_default_ports_and_says_which(tmp_path_factory):
    runs = side_by_side_on_held_defaults(tmp_path_factory)
    for out, code, stderr, pid in zip(runs["outs"], runs["codes"], runs["errs"], runs["pids"], strict=True):
        used = _flew(out, code, stderr)
        assert used["zenoh"] != P.ZENOH_BASE and used["api"] != P.API_BASE
        if used["instance"] is not None:  # PX4's -i offsets: every port and the system id move together
            n = used["instance"]
            assert n >= 1 and used == {"instance": n, "zenoh": P.ZENOH_BASE + n, "api": P.API_BASE + n,
                                       "gcs": P.GCS_BASE + n, "sysid": 1 + n}
        # none of the run's processes reached the held defaults (another program on this machine may: they are
        # its defaults too): no zenoh connection from a child of the run, no datagram from its vehicle's ports
        tcp, udp = runs["tcp"], runs["udp"]
        ours = {pid}
        assert not [r for r in tcp if any(p in ours or ppid in ours for p, ppid in r[1])], tcp
        vehicle_ports = set(map(int, re.search(r"vehicle local udp (\d+),(\d+)", stderr).groups()))
        assert not [r for r in udp if r[0][1] in vehicle_ports], udp


@pytest.mark.slow
@pytest.mark.io
@pytest.mark.timeout(RUN_TIMEOUT_S + 300)
@pytest.mark.exclusive("default-ports-7447-14540")  # the same two runs, flown by whichever of the two comes first
def test_two_stacks_side_by_side_fly_their_own_flights(tmp_path_factory):
    runs = side_by_side_on_held_defaults(tmp_path_factory)
    used = [_flew(*run) for run in zip(runs["outs"], runs["codes"], runs["errs"], strict=True)]
    for key in ("zenoh", "api", "gcs"):
        assert used[0][key] != used[1][key], used
    counts = [_own_frames_only(out) for out in runs["outs"]]
    assert counts[0].shape != counts[1].shape or not np.array_equal(counts[0], counts[1]), "the two flights alike"


@pytest.mark.io
def test_a_port_given_by_its_flag_that_is_taken_is_refused_naming_that_flag(tmp_path, capsys):
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen()
    port = s.getsockname()[1]
    try:
        code = run_main(["--zenoh-port", str(port), "--out", str(tmp_path / "run")])
    finally:
        s.close()
    err = capsys.readouterr().err
    assert code == 2 and f"{port} (zenoh)" in err and "--zenoh-port" in err and "--instance N" in err
    assert "--listen" not in err
    assert not (tmp_path / "run").exists()  # refused before the output folder or any process


@pytest.mark.io
def test_an_instance_in_use_is_refused(tmp_path, capsys):
    n = 37  # an instance far from the ones runs pick (0..9) and from other tests' ephemeral ports
    held = Held(socket.SOCK_DGRAM, P.API_BASE + n)  # (or held by someone else: taken either way)
    try:
        code = run_main(["--instance", str(n), "--out", str(tmp_path / "run")])
    finally:
        held.close()
    err = capsys.readouterr().err
    assert code == 2 and f"--instance {n}" in err and f"{P.API_BASE + n} (api)" in err


@pytest.mark.io
def test_runs_claim_instances_so_simultaneous_starts_differ():
    a = P.choose(instance=None, fixed={})
    try:
        b = P.choose(instance=None, fixed={})
        try:
            assert a.instance is not None and b.instance != a.instance and b.zenoh != a.zenoh
            with pytest.raises(P.PortError, match="another radseek run"):
                P.choose(instance=a.instance, fixed={})
        finally:
            b.release()
    finally:
        a.release()
    team = P.choose(instance=None, fixed={}, n_vehicles=3)  # a team takes PX4 instances N..N+2
    try:
        assert [team.vehicle(v)["api"] for v in range(3)] == [team.api, team.api + 1, team.api + 2]
        assert [team.vehicle(v)["sysid"] for v in range(3)] == [team.sysid, team.sysid + 1, team.sysid + 2]
        other = P.choose(instance=None, fixed={})
        other.release()
        assert other.instance not in range(team.instance, team.instance + 3)
    finally:
        team.release()


def test_no_mcap_shares_the_gcs_port_as_px4_does():
    p = P.Ports(2, **P._derived(2, record=False), gcs_shared=True)
    assert p.gcs == 14550 and [p.vehicle(v)["gcs"] for v in range(2)] == [14550, 14550]
    q = P.Ports(2, **P._derived(2, record=True))
    assert [q.vehicle(v)["gcs"] for v in range(2)] == [14552, 14553] and q.zenoh == 7449 and q.api == 14542


@pytest.mark.io
def test_a_router_port_taken_after_the_check_names_radseek_runs_flags(tmp_path):
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen()
    port = s.getsockname()[1]
    stack = Stack(tmp_path / "logs")
    try:
        with pytest.raises(RuntimeError) as exc:
            start_router(stack, P.Ports(None, zenoh=port, api=0, gcs=0, api_local=0, gcs_local=0, sysid=1))
    finally:
        stack.stop()
        s.close()
    assert "--zenoh-port" in str(exc.value) and "--instance" in str(exc.value) and "--listen" not in str(exc.value)
