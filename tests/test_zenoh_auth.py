"""An authenticated zenoh network (issue 34, item 1): the router admits only the users of the run's credentials
file and lets each put only its own keys. A real `radseek router` on loopback with the credentials `radseek run`
generates; real client sessions (and the third-party `zenoh` command) as each user. A key is "not delivered"
when a subscriber that received every allowed put sent with it, and waited a grace period on top, never saw it.
"""

from __future__ import annotations

import os
import shlex
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from launch.zenoh_auth import stack_env, write_run_credentials
from radseek import topics
from radseek.zenoh_auth import PUTS, CredentialsError, User, find_user, put_keys, read_credentials
from radseek.zenoh_session import RouterRefused, open_session
from radseek_cli.inspect_cli import ZENOH_CLI_RUN_COMMAND
from tests.conftest import free_port

VEHICLES = ["uav0", "uav1"]
WAIT_S = 30.0  # bound on waiting for what must arrive (a loaded host is slow), never asserted
GRACE_S = 1.5  # s a subscriber keeps listening for what must not arrive after everything allowed did


class AuthRouter:
    """`radseek router` with RADSEEK_ZENOH_CREDENTIALS set to a run's generated file."""

    def __init__(self, folder: Path):
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.credentials = write_run_credentials(folder, VEHICLES, self.endpoint)
        self.users = read_credentials(self.credentials)
        self.proc = subprocess.Popen([sys.executable, "-m", "radseek_cli", "router", "--listen", self.endpoint],
                                     env={**os.environ, **stack_env(self.credentials)}, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True)
        self.line = self.proc.stdout.readline()
        # drained for the router's life: an undrained pipe fills with its log (every refused session is logged)
        # and blocks the router in a write, so it never sees SIGTERM (a 60 s teardown in CI)
        self.log: list[str] = []
        threading.Thread(target=lambda: self.log.extend(self.proc.stdout), daemon=True).start()

    def session(self, name: str) -> zenoh.Session:
        user = next(u for u in self.users if u.name == name)
        return open_session(connect=self.endpoint, user=user, wait_for_router_s=WAIT_S)

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


@pytest.fixture
def auth_router(tmp_path):
    r = AuthRouter(tmp_path)
    try:
        assert "listening" in r.line and f"admitting {3 * len(VEHICLES) + 2} users" in r.line, r.line
        yield r
    finally:
        r.stop()


class Inbox:
    """Every sample a subscriber receives, as (key, payload)."""

    def __init__(self, session: zenoh.Session, key: str = "radseek/**"):
        self.got: list[tuple[str, bytes]] = []
        self.cond = threading.Condition()
        self.sub = session.declare_subscriber(key, self._on)

    def _on(self, sample) -> None:
        with self.cond:
            self.got.append((str(sample.key_expr), sample.payload.to_bytes()))
            self.cond.notify_all()

    def wait_for(self, expected: set, timeout: float = WAIT_S) -> None:
        with self.cond:
            self.cond.wait_for(lambda: expected <= set(self.got), timeout)

    def after_grace(self) -> set:
        time.sleep(GRACE_S)
        with self.cond:
            return set(self.got)


def _histogram(seq: int, forged: bool = False) -> bytes:
    counts = [65535] * topics.N_CHANNELS if forged else [seq % 7] * topics.N_CHANNELS
    return topics.Histogram(seq=seq, board_time=seq * 0.1, t=seq * 0.1, duration=0.1, counts=counts).to_bytes()


def _subscribed(inbox: Inbox, publisher: zenoh.Session) -> None:
    """Wait until ``inbox``'s subscription has reached the router (a probe put by the vehicle lands)."""
    key = topics.key(topics.POSE)
    deadline = time.monotonic() + WAIT_S
    n = 0
    while time.monotonic() < deadline:
        n += 1
        probe = (key, f"probe {n}".encode())
        publisher.put(*probe)
        inbox.wait_for({probe}, timeout=0.2)
        if probe in inbox.got:
            return
    raise AssertionError(f"the subscription did not reach the router in {WAIT_S:g} s")


# ------------------------------------------------------------------------------------------ who gets in


@pytest.mark.io
def test_a_session_without_the_runs_credentials_is_refused(auth_router):
    observer = next(u for u in auth_router.users if u.name == "observer")
    attempts = {"no credentials": None, "a wrong password": User("detector@uav0", "not-the-secret"),
                "a name not in the file": User("intruder", observer.password)}
    for what, user in attempts.items():
        with pytest.raises(RouterRefused) as err:
            open_session(connect=auth_router.endpoint, user=user, wait_for_router_s=WAIT_S)
        msg = str(err.value)
        assert auth_router.endpoint in msg and "refused" in msg and "\n" not in msg, what
        assert observer.password not in msg, what
        if user is None:
            assert "RADSEEK_ZENOH_CREDENTIALS" in msg
    with auth_router.session("observer"):  # the control: the file's own user gets in
        pass


# ------------------------------------------------------------------------------------------ who puts what


@pytest.mark.io
def test_each_process_puts_only_its_own_keys(auth_router):
    """Every stack user puts its own keys and tries every other role's (and another vehicle's): a subscriber
    with the mission's credentials receives exactly the allowed puts."""
    k = topics.key
    tries = {  # user -> keys it puts (its own first)
        "detector@uav0": [k(topics.HISTOGRAM), k(topics.RAW_FRAME), k(topics.SIM_CLOCK), k(topics.MISSION_LOCKSTEP),
                          k(topics.HISTOGRAM, "uav1"), k(topics.ESTIMATE, topics.TEAM)],
        "vehicle@uav0": [k(topics.SIM_CLOCK), k(topics.SIM_TRUTH_POSE), k(topics.HISTOGRAM), k(topics.ESTIMATE),
                         k(topics.SIM_CLOCK, "uav1")],
        "mission@uav0": [k(topics.MISSION_LOCKSTEP), k(topics.ESTIMATE), k(topics.PLAN), k(topics.TEAM_STATUS),
                         k(topics.ESTIMATE, topics.TEAM), k(topics.SIM_CLOCK), k(topics.HISTOGRAM),
                         k(topics.MISSION_LOCKSTEP, "uav1")],
        "recorder": [k(topics.HISTOGRAM), k(topics.SIM_CLOCK)],
        "observer": [k(topics.HISTOGRAM), k(topics.SIM_CLOCK), k(topics.MISSION_LOCKSTEP)],
    }
    allowed = {"detector@uav0": 2, "vehicle@uav0": 2, "mission@uav0": 5, "recorder": 0, "observer": 0}
    sessions = {name: auth_router.session(name) for name in tries}
    with auth_router.session("mission@uav1") as reader:
        inbox = Inbox(reader)
        _subscribed(inbox, sessions["vehicle@uav0"])
        expected, forbidden = set(), set()
        for name, keys in tries.items():
            for i, key in enumerate(keys):
                sample = (key, f"from {name}".encode())
                sessions[name].declare_publisher(key).put(sample[1])  # as the processes put: a declared publisher
                (expected if i < allowed[name] else forbidden).add(sample)
        inbox.wait_for(expected)
        got = inbox.after_grace()
    for s in sessions.values():
        s.close()
    assert expected <= got, f"allowed puts not delivered: {sorted(expected - got)}"
    assert not got & forbidden, f"forbidden puts delivered: {sorted(got & forbidden)}"


@pytest.mark.io
def test_a_forged_histogram_flood_does_not_reach_the_mission(auth_router):
    """An unauthenticated process cannot flood at all; one holding another user's secret floods forged (valid)
    histograms on the detector's key, and the mission receives the detector's frames, all of them and only them."""
    with pytest.raises(RouterRefused):
        open_session(connect=auth_router.endpoint, user=None, wait_for_router_s=WAIT_S)
    n_genuine, n_forged = 50, 5000
    key = topics.key(topics.HISTOGRAM)
    with auth_router.session("mission@uav0") as mission, auth_router.session("detector@uav0") as detector, \
            auth_router.session("observer") as observer, auth_router.session("vehicle@uav0") as vehicle:
        inbox = Inbox(mission, key)
        _subscribed(Inbox(mission), vehicle)
        flooders = [observer.declare_publisher(key), vehicle.declare_publisher(key)]
        real = topics.declare_publisher(detector, topics.HISTOGRAM)
        genuine = set()
        for seq in range(n_forged):
            flooders[seq % 2].put(_histogram(seq, forged=True))
            if seq % (n_forged // n_genuine) == 0:
                payload = _histogram(seq)
                real.put(payload)
                genuine.add((key, payload))
        inbox.wait_for(genuine)
        got = inbox.after_grace()
    forged = {p for _, p in got if topics.Histogram.from_bytes(p).counts[0] == 65535}
    assert len(genuine) == n_genuine and got == genuine, f"{len(forged)} forged of {len(got)} received"


# ------------------------------------------------------------------------------------------ inspection


@pytest.mark.io
def test_zenoh_cli_watches_with_the_observer_config(auth_router):
    """docs/topics.md's zenoh-cli recipe for a run, with the run's OUT/zenoh/observer.json5, prints the stack's
    messages (the router refuses the recipe without credentials: test_a_session_without_...)."""
    out = auth_router.credentials.parent.parent  # the run's OUT folder
    cmd = shlex.split(ZENOH_CLI_RUN_COMMAND.replace("OUT/", f"{out}/"))  # the documented command
    cmd[0] = str(Path(sys.executable).parent / "zenoh")
    cli = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(cli.stdout), daemon=True)
    reader.start()
    try:
        with auth_router.session("vehicle@uav0") as vehicle:
            deadline = time.monotonic() + WAIT_S
            t = 0.0
            while not any("sim/clock" in ln for ln in lines) and time.monotonic() < deadline:
                t += 0.1
                vehicle.put(topics.key(topics.SIM_CLOCK), topics.SimClock(t=t, speedup=1.0).to_bytes())
                time.sleep(0.1)
    finally:
        cli.terminate()
        cli.wait(30)
    clock = [ln for ln in lines if ln.startswith(topics.key(topics.SIM_CLOCK))]
    assert clock and '"speedup": 1.0' in clock[0], (lines, cli.stderr.read()[-2000:])


# ------------------------------------------------------------------------------------------ the contract


def test_every_declared_topic_is_put_by_exactly_one_role():
    """A new topic in radseek/topics.py with no role to put it would be denied by every router: the ACL's
    key expressions cover each declared key of a vehicle once, and the team's estimate by the mission only."""
    users = [User(f"{role}@uav0", "x") for role in PUTS]
    declared = [*topics.PAYLOADS, topics.RAW_FRAME]
    for topic in declared:
        owners = [u.name for u in users if any(zenoh.KeyExpr(e).includes(zenoh.KeyExpr(topics.key(topic)))
                                               for e in put_keys(u))]
        assert len(owners) == 1, (topic, owners)
    team = topics.key(topics.ESTIMATE, topics.TEAM)
    assert [u.name for u in users if any(zenoh.KeyExpr(e).includes(zenoh.KeyExpr(team)) for e in put_keys(u))] \
        == ["mission@uav0"]
    assert put_keys(User("groundstation", "x")) == []


@pytest.mark.parametrize("text, line, says", [
    ("", None, "no users"),
    ("observer:a\n\nrecorder:b\n", 2, "USER:PASSWORD"),
    ("# users\nobserver:a\n", 1, "USER:PASSWORD"),
    ("observer\n", 1, "USER:PASSWORD"),
    ("pilot@uav0:a\n", 1, "role 'pilot'"),
    ("detector@uav0:a\ndetector@uav0:b\n", 2, "given twice"),
    ("detector@uav/0:a\n", 1, "ROLE@VEHICLE"),
])
def test_a_bad_credentials_file_is_named_by_line(tmp_path, text, line, says):
    path = tmp_path / "credentials"
    path.write_text(text)
    with pytest.raises(CredentialsError) as err:
        read_credentials(path)
    msg = str(err.value)
    assert str(path) in msg and says in msg and "\n" not in msg
    assert (f"line {line}:" in msg) if line else "line" not in msg


def test_a_process_finds_its_own_line_or_says_which_is_missing(tmp_path):
    users = [User("detector.board7@uav1", "a"), User("groundstation", "b"), User("mission@uav0", "c")]
    assert find_user(users, "detector", "uav1").name == "detector.board7@uav1"  # a labelled identity
    assert find_user(users, None).name == "groundstation"  # any reader's line
    assert find_user(users, "mission", "uav0").name == "mission@uav0"
    with pytest.raises(CredentialsError, match="no user for vehicle of uav0.*'vehicle@uav0:PASSWORD'"):
        find_user(users, "vehicle", "uav0", source="FILE")


def test_run_credentials_are_private_and_unguessable(tmp_path):
    a, b = (write_run_credentials(tmp_path / run, VEHICLES, "tcp/127.0.0.1:7447") for run in ("a", "b"))
    for path in (a, b):
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
        assert stat.S_IMODE(path.parent.stat().st_mode) == 0o700
        assert stat.S_IMODE((path.parent / "observer.json5").stat().st_mode) == 0o600
    ua, ub = read_credentials(a), read_credentials(b)
    assert [u.name for u in ua] == [u.name for u in ub]
    passwords = [u.password for u in ua + ub]
    assert len(set(passwords)) == len(passwords) and min(len(p) for p in passwords) >= 32
